"""Frame patches (deform.frame_patches): a frame's own Gaussians where its hull holds movers
that the deformed segment copy does not reach."""

from __future__ import annotations

import torch

from conftest import stage_smoke_cfg
from relaygs.data import Scene
from relaygs.model import SH_C0, GaussianSet
from relaygs.pipeline.artifact import Artifact
from relaygs.stages import SPECS, SceneModel
from relaygs.stages.deform import DeformConfig, _starting_model
from relaygs.stages.frame_hulls import FrameHulls
from relaygs.stages.frame_patches import _moved, _shown_means, frame_patches
from relaygs.stages.hull_prefit import prefit_foreground_motion
from relaygs.train.scene_model import GAMMA, SEGMENT, foreground_with_segments
from relaygs.train.segment_plan import SegmentPlan


def _tagged_model(tags: list[int], num_frames: int, k: int) -> SceneModel:
    points = torch.rand(len(tags), 3)
    foreground = GaussianSet.from_points(points, torch.rand(len(tags), 3), 0)
    background = GaussianSet.from_points(torch.rand(4, 3), torch.rand(4, 3), 0)
    return SceneModel(
        stage="deform",
        background=background,
        foreground=foreground_with_segments(foreground, torch.tensor(tags)),
        segments=SegmentPlan.uniform(num_frames, k),
        eps2d=0.1,
    )


def test_a_frame_shows_its_segments_copy_and_its_own_patch_alone() -> None:
    model = _tagged_model([0, 0, 1, 2 + 2, 2 + 3, 2 + 0], num_frames=4, k=2)  # S = 2
    assert model.frame_patch_tag(3) == 5
    assert model.in_frame_patches().tolist() == [False, False, False, True, True, True]
    assert model.foreground_rows(0).tolist() == [0, 1, 5]
    assert model.foreground_rows(1).tolist() == [0, 1]
    assert model.foreground_rows(2).tolist() == [2, 3]
    assert model.foreground_rows(3).tolist() == [2, 4]


def _prefitted(scene: Scene, relayed: Artifact) -> tuple[SceneModel, FrameHulls]:
    """The relayed model with γ and a field prefitted to the scene's hulls (so it moves them)."""
    from relaygs.train.views import TrainViews

    source = SceneModel.from_artifact(relayed)
    model = _starting_model(source, DeformConfig(), scene, 0, source.blur())
    views = TrainViews(scene, torch.device("cpu"))
    hulls = FrameHulls.carve(views, source.background, source.blur(), 0)
    rates = {"grid": 6.4e-3, "mlp": 6.4e-4}
    prefit_foreground_motion(model, hulls, 30, rates, {}, 1.0, scene.extent, seed=0)
    return model, hulls


def test_patches_cover_exactly_the_hull_points_the_shown_copy_misses(
    stage_scene: Scene, stage_relayed: Artifact
) -> None:
    model, carved = _prefitted(stage_scene, stage_relayed)
    frame, voxel = 5, carved.voxel[5]
    with torch.no_grad():
        shown = _shown_means(model, frame)
    far = shown.mean(dim=0) + torch.tensor([[3.0, 0.0, 0.0], [3.0, 0.1, 0.0], [3.0, 0.0, 0.1]])
    near = shown[:4] + 0.5 * voxel
    hulls = FrameHulls({frame: torch.cat([near, far])}, {frame: voxel}, {frame: torch.rand(7, 3)})
    patches = frame_patches(model, hulls, per_frame=10, opacity=0.5, seed=0)
    assert patches is not None and len(patches) == 3
    assert patches.buffers[SEGMENT].tolist() == [model.frame_patch_tag(frame)] * 3
    assert torch.equal(patches.params[GAMMA], torch.zeros(3, 3))
    assert torch.allclose(patches.opacities, torch.full((3,), 0.5))
    rgb = patches.params["sh_dc"].detach()[:, 0] * SH_C0 + 0.5
    assert torch.allclose(rgb, hulls.colours[frame][4:].clamp(0, 1), atol=1e-6)
    # the field moves the far points (the prefit), and one fixed-point step lands each seed
    # nearer its point than a seed placed at the point itself would land (how near depends on
    # the field's smoothness there, which differs with the CPU's rounding)
    with torch.no_grad():
        placed = _moved(model, patches.means.detach(), frame)
        moved = (_moved(model, far, frame) - far).norm(dim=1)
    assert float(moved.min()) > 0.01 * voxel
    assert bool(((placed - far).norm(dim=1) < moved).all())
    capped = frame_patches(model, hulls, per_frame=2, opacity=0.5, seed=0)
    assert capped is not None and len(capped) == 2
    hulls_reached = FrameHulls({frame: near}, {frame: voxel}, {frame: torch.rand(4, 3)})
    assert frame_patches(model, hulls_reached, per_frame=10, opacity=0.5, seed=0) is None


def test_deform_with_frame_patches_renders_each_patch_at_its_frame_only(
    stage_scene: Scene, stage_relayed: Artifact
) -> None:
    cfg = stage_smoke_cfg(deform={"steps": 4, "frame_patches": 50})
    artifact = SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
    model = SceneModel.from_artifact(artifact)
    in_patches = model.in_frame_patches()
    assert artifact.meta["metrics"]["num_fg_in_frame_patches"] == int(in_patches.sum())
    tags = model.foreground.buffers[SEGMENT]
    patched = sorted({int(tag) - model.num_segments for tag in tags[in_patches]})
    assert patched and set(patched) <= set(range(stage_scene.num_frames))
    counts = torch.bincount(tags.long())[model.num_segments :]
    assert int(counts.max()) <= 50
    frame = patched[0]
    shown = set(model.foreground_rows(frame).tolist())
    own = set((tags == model.frame_patch_tag(frame)).nonzero()[:, 0].tolist())
    assert own <= shown
    others = set(in_patches.nonzero()[:, 0].tolist()) - own
    assert not shown & others
    assert all(torch.isfinite(p).all() for p in model.foreground.params.values())
