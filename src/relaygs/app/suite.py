"""What the app needs from the stages in one object, so tests can run it on fake stages."""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from relaygs.app.evaluation import EvaluateFn
from relaygs.app.plan import StageValidator
from relaygs.pipeline import Artifact
from relaygs.pipeline.dag import CanonicalFn, StageFn

LogSink = Callable[..., None]  # receives `(stage, step, scalars, images=None)`
ScalarRecord = tuple[int, dict[str, float]]  # a step and the scalars a stage logged at it


@dataclass(frozen=True)
class StageSuite:
    """Stage functions, schema versions, config canonicalisation and validation, evaluation,
    rendering, log-sink hooks, accepted upstream types and an artifact's logged scalars."""

    stages: Mapping[str, StageFn]
    schema_versions: Mapping[str, int]
    canonical: CanonicalFn
    validate: StageValidator
    evaluate: EvaluateFn
    render_model: Callable[[Artifact, Any, float], torch.Tensor]
    add_sink: Callable[[LogSink], None]
    remove_sink: Callable[[LogSink], None]
    accepted_upstream: Mapping[str, Collection[str]] = field(default_factory=dict)
    logged_scalars: Callable[[Artifact], list[ScalarRecord]] = lambda artifact: []


def load_stage_suite() -> StageSuite:
    """The real stages, from the specs of `relaygs.stages.SPECS`."""
    from relaygs import stages
    from relaygs.stages.common import logged_scalars
    from relaygs.train import log

    specs = stages.SPECS.values()
    return StageSuite(
        stages={spec.name: spec.run for spec in specs},
        schema_versions={spec.name: spec.schema_version for spec in specs},
        canonical=stages.canonical_config,
        validate=stages.validate_config,
        evaluate=stages.evaluate,
        render_model=stages.render_model,
        add_sink=log.add_sink,
        remove_sink=log.remove_sink,
        accepted_upstream={spec.name: spec.upstream for spec in specs},
        logged_scalars=logged_scalars,
    )
