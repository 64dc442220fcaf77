"""Stage DAG machinery: content-addressed artifact store, keys, checkpoints, pipeline runner."""

from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.checkpoint import StageCheckpointer, TrainingState
from relaygs.pipeline.context import BuildContext, current_build
from relaygs.pipeline.dag import NodeReport, PipelineRun, run_pipeline
from relaygs.pipeline.integrity import CorruptArtifactError
from relaygs.pipeline.keys import artifact_key, key_config
from relaygs.pipeline.manifest import BUILT_BY, LineageEntry, Manifest
from relaygs.pipeline.spec import Node, Pipeline, available_pipelines, load_pipeline
from relaygs.pipeline.store import ArtifactStore, BuildInfo, MissingArtifactError

__all__ = [
    "BUILT_BY",
    "Artifact",
    "ArtifactStore",
    "BuildContext",
    "BuildInfo",
    "CorruptArtifactError",
    "LineageEntry",
    "Manifest",
    "MissingArtifactError",
    "Node",
    "NodeReport",
    "Pipeline",
    "PipelineRun",
    "StageCheckpointer",
    "TrainingState",
    "artifact_key",
    "available_pipelines",
    "current_build",
    "key_config",
    "load_pipeline",
    "run_pipeline",
]
