"""The stages and the renders on CUDA: the smoke lineage as on the CPU, within float noise
(skipped without a GPU; run where one is lent)."""

import cv2
import numpy as np
import pytest
import torch

from conftest import STAGE_K, stage_smoke_cfg
from relaygs.renders import RenderSettings, write_renders
from relaygs.stages import SPECS, relay
from relaygs.train.scene_model import SEGMENT, SceneModel, core_only
from relaygs.train.segment_plan import SegmentPlan
from relaygs.train.views import TrainViews

DEVICE = "cuda"
pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def _lineage(scene, device):
    cfg = stage_smoke_cfg(train={"device": device, "progress": False})
    decoupled = SPECS["decouple"].run(scene, {}, cfg)
    relayed = SPECS["relay"].run(scene, {"decouple": decoupled}, cfg)
    return [decoupled, relayed, SPECS["deform"].run(scene, {"relay": relayed}, cfg)]


def test_the_smoke_lineage_on_the_gpu_matches_the_cpu(stage_scene):
    for cpu, gpu in zip(_lineage(stage_scene, "cpu"), _lineage(stage_scene, DEVICE), strict=True):
        for name, tensor in gpu.tensors.items():
            assert tensor.device.type == "cpu", f"{gpu.stage} {name} left on {tensor.device}"
            if tensor.is_floating_point():
                assert bool(torch.isfinite(tensor).all()), f"{gpu.stage} {name} not finite"
        expected, got = cpu.meta["metrics"]["final_loss"], gpu.meta["metrics"]["final_loss"]
        assert abs(got - expected) <= 0.05 * expected, f"{gpu.stage}: {got} vs {expected}"


def test_gpu_renders_match_cpu_renders(stage_scene, stage_deformed, tmp_path):
    settings = RenderSettings(frame_stride=4, fps=None)
    for device in ("cpu", DEVICE):
        model = SceneModel.from_artifact(stage_deformed).to(device)
        write_renders(stage_scene, model, tmp_path / device, settings, progress=False)
    written = sorted((tmp_path / "cpu").rglob("*.png"))
    assert written
    for png in written:
        cpu = cv2.imread(str(png)).astype(np.int16)
        gpu = cv2.imread(str(tmp_path / DEVICE / png.relative_to(tmp_path / "cpu")))
        assert np.abs(cpu - gpu.astype(np.int16)).max() <= 1, png.name


def test_carved_copies_join_hull_seeds_and_replicas_on_the_gpu(
    stage_scene, stage_decoupled, monkeypatch
):
    # segment 0's hull holds points (seeds carved on the CPU), segment 1's is empty (replica)
    generator = torch.Generator().manual_seed(0)
    hull = (torch.rand(30, 3, generator=generator), torch.rand(30, 3, generator=generator), 0.05)
    monkeypatch.setattr(
        relay, "frame_hull", lambda views, renders, frame, *_: hull if frame < STAGE_K else None
    )
    source = SceneModel.from_artifact(stage_decoupled).to(DEVICE)
    replica = core_only(source.foreground)
    copies = relay.carved_copies(
        TrainViews(stage_scene, source.background.means.device),
        relay.BackgroundRenders(source.background, source.eps2d),
        replica,
        relay.RelayConfig(k=STAGE_K),
        SegmentPlan.uniform(stage_scene.num_frames, STAGE_K),
        seed=0,
    )
    for name, tensor in copies.to_tensors().items():
        if tensor.ndim:
            assert tensor.device.type == DEVICE, f"{name} on {tensor.device}"
    seeds, replicas = torch.bincount(copies.buffers[SEGMENT].long().cpu(), minlength=2).tolist()
    assert seeds > 0 and replicas == len(replica) > 0
