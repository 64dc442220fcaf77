"""Stage artifacts round-trip exactly through the on-disk form and render the same images."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact, read_artifact_files, write_artifact_files
from relaygs.stages import SceneModel, render_model
from relaygs.stages.model_render import ModelRenderer


def _round_trip(artifact: Artifact, folder: Path) -> Artifact:
    folder.mkdir()
    write_artifact_files(folder, artifact)
    return read_artifact_files(folder, artifact.stage)


@pytest.mark.parametrize("name", ["stage_decoupled", "stage_relayed", "stage_deformed"])
def test_round_trip_is_exact(
    name: str, request: pytest.FixtureRequest, stage_scene: Scene, tmp_path: Path
) -> None:
    artifact = request.getfixturevalue(name)
    loaded = _round_trip(artifact, tmp_path / name)
    assert loaded.meta == artifact.meta
    assert sorted(loaded.tensors) == sorted(artifact.tensors)
    for key, tensor in artifact.tensors.items():
        assert loaded.tensors[key].dtype == tensor.dtype, key
        assert torch.equal(loaded.tensors[key], tensor), key
    # the model rebuilt from either renders bit-identical images, also between frames
    camera = stage_scene.test_cameras[0]
    for time in (0.0, 0.37, 1.0):
        before = render_model(artifact, camera, time)
        after = render_model(loaded, camera, time)
        assert before.shape == (camera.height, camera.width, 3)
        assert torch.equal(before, after)
    rebuilt = SceneModel.from_artifact(loaded).to_artifact(
        {k: v for k, v in artifact.meta.items() if k not in ("num_frames", "k")}
    )
    for key, tensor in artifact.tensors.items():
        assert torch.equal(rebuilt.tensors[key], tensor), key


def test_renders_follow_time(stage_deformed: Artifact, stage_scene: Scene) -> None:
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    camera = stage_scene.test_cameras[1]
    first, last = (renderer.render([camera], t)[0] for t in (0.0, 1.0))
    assert float(first.min()) >= 0.0 and float(first.max()) <= 1.0
    assert not torch.equal(first, last)


def test_missing_meta_is_an_input_error(stage_relayed: Artifact) -> None:
    broken = Artifact(stage_relayed.stage, stage_relayed.tensors, {"k": 4})
    with pytest.raises(InputError, match="num_frames"):
        SceneModel.from_artifact(broken)
