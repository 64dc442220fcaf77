"""The training machinery the stages share; it imports nothing from the stages or the app."""
