"""The training machinery the stages share: loop, session, rendering, losses, views, the scene
model, evaluation helpers and the named step budgets. It imports nothing from `relaygs.stages`
or the app, so a stage imports it and never the other way round."""
