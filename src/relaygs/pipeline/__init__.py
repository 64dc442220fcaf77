"""Stage DAG machinery: content-addressed artifact store, keys, checkpoints, pipeline runner."""

from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.dag import NodeReport, PipelineRun, run_pipeline
from relaygs.pipeline.integrity import CorruptArtifactError
from relaygs.pipeline.keys import artifact_key, key_config
from relaygs.pipeline.manifest import BUILT_BY, LineageEntry
from relaygs.pipeline.spec import Node, Pipeline, load_pipeline
from relaygs.pipeline.store import ArtifactStore

__all__ = [
    "BUILT_BY",
    "Artifact",
    "ArtifactStore",
    "CorruptArtifactError",
    "LineageEntry",
    "Node",
    "NodeReport",
    "Pipeline",
    "PipelineRun",
    "artifact_key",
    "key_config",
    "load_pipeline",
    "run_pipeline",
]
