"""Stage artifacts round-trip exactly through the on-disk form and render the same images."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.field import ColorAffine
from relaygs.model import CORE_PARAMS, GaussianSet
from relaygs.pipeline.artifact import Artifact, read_artifact_files, write_artifact_files
from relaygs.stages import SceneModel, render_model
from relaygs.stages.train_settings import TrainSettings
from relaygs.train.model_render import ModelRenderer
from relaygs.train.render import splat
from relaygs.train.scene_model import (
    SEGMENT,
    build_field,
    foreground_with_segments,
    replicate_foreground,
)
from relaygs.train.segment_plan import SegmentPlan


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
    renders = []
    for time in (0.0, 0.37, 1.0):
        renders.append(render_model(artifact, camera, time))
        assert renders[-1].shape == (camera.height, camera.width, 3)
        assert torch.equal(renders[-1], render_model(loaded, camera, time))
        assert float(renders[-1].min()) >= 0.0 and float(renders[-1].max()) <= 1.0
    assert name != "stage_deformed" or not torch.equal(renders[0], renders[-1])  # it moves
    rebuilt = SceneModel.from_artifact(loaded).to_artifact(
        {k: v for k, v in artifact.meta.items() if k not in ("num_frames", "k")}
    )
    for key, tensor in artifact.tensors.items():
        assert torch.equal(rebuilt.tensors[key], tensor), key


def _tiny_deformed() -> Artifact:
    """A deform-like artifact of a few Gaussians with a small field and a colour affine."""
    points = torch.rand(4, 3) * 2 - 1
    gaussians = GaussianSet.from_points(points, torch.rand(4, 3))
    settings = {
        "aabb": [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],
        "time_resolution": 2,
        "isolate_fg_bg": True,
        "multires": [1],
        "spatial_resolution": 4,
        "channels": 2,
        "width": 4,
        "depth": 0,
    }
    model = SceneModel(
        stage="deform",
        background=gaussians,
        foreground=foreground_with_segments(gaussians, torch.zeros(4)),
        segments=SegmentPlan.uniform(2, 2),
        eps2d=0.1,
        field=build_field(settings),
        field_settings=settings,
        affine=ColorAffine(2),
        affine_cameras=[1, 2],
    )
    return model.to_artifact({})


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda meta, tensors: ([1], tensors), "meta is a list"),
        (lambda meta, tensors: ({"k": 4}, tensors), "meta 'num_frames' missing"),
        (lambda meta, tensors: ({**meta, "k": 0}, tensors), "meta 'k' missing or not an int >= 1"),
        (lambda meta, tensors: ({**meta, "segment_starts": [0, 5]}, tensors), "segment starts"),
        (lambda meta, tensors: ({**meta, "segment_starts": "0"}, tensors), "'segment_starts'"),
        (lambda meta, tensors: ({**meta, "field": "x"}, tensors), "its field does not match"),
        (lambda meta, tensors: ({**meta, "eps2d": -1.0}, tensors), "meta 'eps2d'"),
        (lambda meta, tensors: ({**meta, "eps2d": "0.1"}, tensors), "meta 'eps2d'"),
        (lambda meta, tensors: ({**meta, "antialiased": 1}, tensors), "meta 'antialiased'"),
        (
            lambda meta, tensors: ({**meta, "field": {**meta["field"], "width": 5}}, tensors),
            "its field does not match its settings (Error(s) in loading state_dict",
        ),
        (
            lambda meta, tensors: (meta, {k: v for k, v in tensors.items() if "offset" not in k}),
            "its affine does not match its settings",
        ),
    ],
)
def test_meta_or_module_tensors_that_do_not_fit_are_an_input_error(edit, message) -> None:
    artifact = _tiny_deformed()
    assert SceneModel.from_artifact(artifact).field is not None
    meta, tensors = edit(artifact.meta, artifact.tensors)
    with pytest.raises(InputError) as caught:
        SceneModel.from_artifact(Artifact("deform", tensors, meta))
    assert str(caught.value).startswith("deform artifact: ") and message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_a_model_renders_with_the_blur_its_stage_trained_with(
    stage_decoupled: Artifact, stage_deformed: Artifact, stage_scene: Scene
) -> None:
    """The stage's `train.eps2d` and `train.antialiased` are recorded in its artifact and every
    render of the model uses them; an artifact written before they were recorded renders with
    3DGS's classic 0.3, as it trained."""
    trained = TrainSettings().blur()
    assert trained["eps2d"] != 0.3
    for artifact in (stage_decoupled, stage_deformed):
        for name, value in trained.items():
            assert artifact.meta[name] == artifact.meta["config"]["train"][name] == value
    camera = stage_scene.test_cameras[0]
    model = SceneModel.from_artifact(stage_deformed)
    recorded = render_model(stage_deformed, camera, 0.5)
    renderer = ModelRenderer(model)
    direct = splat(renderer.parts_at(0.5), [camera], renderer.sh_degree, **trained).images[0]
    assert torch.equal(recorded, direct.clamp(0.0, 1.0))
    older = {k: v for k, v in stage_deformed.meta.items() if k not in trained}
    old_model = SceneModel.from_artifact(Artifact("deform", stage_deformed.tensors, older))
    assert (old_model.eps2d, old_model.antialiased) == (0.3, False)
    blurred = render_model(Artifact("deform", stage_deformed.tensors, older), camera, 0.5)
    assert (blurred - recorded).abs().max() > 1e-3
    toggled = {**stage_deformed.meta, "antialiased": not trained["antialiased"]}
    other_mode = render_model(Artifact("deform", stage_deformed.tensors, toggled), camera, 0.5)
    assert (other_mode - recorded).abs().max() > 1e-3


def test_segment_buffers_are_made_on_the_device_of_the_set() -> None:
    # the meta device stands in for a GPU: a CPU buffer beside its parameters would fail there
    tensors = GaussianSet.from_points(torch.rand(3, 3), torch.rand(3, 3)).to_tensors()
    gaussians = GaussianSet({name: tensors[name].to("meta") for name in CORE_PARAMS})
    tagged = foreground_with_segments(gaussians, torch.zeros(3))
    replicated = replicate_foreground(tagged, 2)
    for made in (tagged, replicated):
        assert made.buffers[SEGMENT].device == made.means.device == torch.device("meta")
    assert replicated.buffers[SEGMENT].shape == (6,)
