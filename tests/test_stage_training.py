"""Training loop contracts: resume equals an uninterrupted run, divergence stops and writes
nothing, live metrics reach the log sinks."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import torch

from conftest import stage_smoke_cfg
from refusals import refused
from relaygs.data import Scene
from relaygs.errors import DivergenceError, Interrupted
from relaygs.metrics import ssim
from relaygs.pipeline.artifact import Artifact, write_artifact_files
from relaygs.pipeline.checkpoint import StageCheckpointer
from relaygs.pipeline.context import BuildContext, building
from relaygs.pipeline.store import ArtifactStore
from relaygs.stages import SPECS
from relaygs.stages import relay as relay_module
from relaygs.stages.common import logged_scalars
from relaygs.train import log
from relaygs.train.loop import ScalarHistory
from relaygs.train.loss import batch_psnr, photometric_loss
from relaygs.train.session import TrainingSession

KEY = "ab" * 32


class KilledError(Exception):
    """Stands in for the process being killed mid-stage."""


def _kill_at(step_to_die: int, error: type[BaseException] = KilledError):
    def sink(stage: str, step: int, scalars, images=None) -> None:
        if step == step_to_die:
            raise error(f"{stage} killed at {step}")

    return sink


def _run(
    stage: str,
    scene: Scene,
    upstream: dict,
    cfg: dict,
    root: Path,
    kill_at: int | None = None,
    error: type[BaseException] = KilledError,
):
    sink = _kill_at(kill_at, error) if kill_at is not None else None
    if sink is not None:
        log.add_sink(sink)
    try:
        with building(BuildContext(root, stage, KEY)):
            return SPECS[stage].run(scene, upstream, cfg)
    finally:
        if sink is not None:
            log.remove_sink(sink)


@pytest.mark.parametrize("stage", ["decouple", "relay", "deform"])
def test_resumed_run_ends_bitwise_equal_to_uninterrupted(
    stage: str,
    stage_scene: Scene,
    stage_decoupled: Artifact,
    stage_relayed: Artifact,
    tmp_path: Path,
) -> None:
    """docs/artifacts.md: bitwise on one machine. (The relay's frozen-background cache starts
    empty on resume: what it holds must not depend on the steps before the checkpoint.)"""
    upstreams = {
        "decouple": {},
        "relay": {"decouple": stage_decoupled},
        "deform": {"relay": stage_relayed},
    }
    upstream = upstreams[stage]
    # checkpoints every 5 steps, densification every 4: the resume restores changed shapes
    cfg = stage_smoke_cfg(train={"checkpoint_every": 5, "log_every": 1})
    whole = _run(stage, stage_scene, upstream, cfg, tmp_path / "a")
    with pytest.raises(KilledError):
        _run(stage, stage_scene, upstream, cfg, tmp_path / "b", kill_at=13)
    resumed = _run(stage, stage_scene, upstream, cfg, tmp_path / "b")
    assert resumed.meta["metrics"]["resumed_from"] == 10
    assert whole.meta["metrics"]["resumed_from"] == 0
    assert sorted(resumed.tensors) == sorted(whole.tensors)
    for key, tensor in whole.tensors.items():
        assert torch.equal(resumed.tensors[key], tensor), key
    for key in ("initial_loss", "final_loss"):
        assert resumed.meta["metrics"][key] == whole.meta["metrics"][key]
    # the curves before the kill come back from the checkpoint
    assert resumed.meta["logged_scalars"] == whole.meta["logged_scalars"]
    assert [step for step, _ in whole.meta["logged_scalars"]] == list(range(1, 21))


def test_ctrl_c_names_the_step_and_the_checkpoint_a_rerun_resumes_from(
    stage_scene: Scene, tmp_path: Path
) -> None:
    cfg = stage_smoke_cfg(train={"checkpoint_every": 5, "log_every": 1})
    steps = cfg["decouple"]["steps"]
    with refused(Interrupted, "decouple", f"step 12 of {steps}", "step 10") as caught:
        _run("decouple", stage_scene, {}, cfg, tmp_path, kill_at=13, error=KeyboardInterrupt)
    assert isinstance(caught.value, KeyboardInterrupt)
    resumed = _run("decouple", stage_scene, {}, cfg, tmp_path)
    assert resumed.meta["metrics"]["resumed_from"] == 10


def test_divergence_names_stage_step_tensor_and_stores_nothing(
    stage_scene: Scene, tmp_path: Path
) -> None:
    store = ArtifactStore(tmp_path)
    cfg = stage_smoke_cfg(decouple={"lr": {"sh_dc": 1e36}}, train={"checkpoint_every": 1})
    with pytest.raises(DivergenceError) as caught:
        store.get_or_build(
            "decouple",
            KEY,
            lambda: SPECS["decouple"].run(stage_scene, {}, cfg),
            config={},
            lineage=[],
        )
    found = re.fullmatch(
        r"stage 'decouple' diverged at step (\d+): tensor '([\w.]+)' has .*", str(caught.value)
    )
    assert found is not None, str(caught.value)
    step = int(found.group(1))
    assert store.list() == []
    checkpoints = store.root / "decouple" / f"{KEY}.ckpt"
    saved = [int(p.name.split("-")[1]) for p in checkpoints.glob("step-*")]
    assert all(saved_step < step for saved_step in saved)


@pytest.mark.parametrize("group", ["sh_dc", "log_scales"])
def test_divergence_names_the_parameter_whose_update_went_non_finite_first(
    stage_scene: Scene, group: str
) -> None:
    # the symptom (a non-finite loss or gradient at step 2) follows from the update of step 1
    cfg = stage_smoke_cfg(decouple={"lr": {group: 1e38}, "steps": 5})
    with refused(DivergenceError, "'decouple'", "step 2", "step 1", f"all.{group}"):
        SPECS["decouple"].run(stage_scene, {}, cfg)


def test_non_finite_optimiser_step_stops_before_its_checkpoint(
    stage_scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    apply_gradients = TrainingSession.apply_gradients

    def poisoned_at_step_4(self, renders, step):
        reports = apply_gradients(self, renders, step)
        if step == 4:
            with torch.no_grad():
                next(iter(self.sets.values())).params["opacity_logits"][0] = float("inf")
        return reports

    monkeypatch.setattr(TrainingSession, "apply_gradients", poisoned_at_step_4)
    cfg = stage_smoke_cfg(train={"checkpoint_every": 2})
    with refused(DivergenceError, "'decouple'", "step 4", "'all.opacity_logits'"):
        _run("decouple", stage_scene, {}, cfg, tmp_path)
    checkpoints = tmp_path / "decouple" / f"{KEY}.ckpt"
    assert sorted(p.name for p in checkpoints.glob("step-*")) == [f"step-{2:012d}"]


def test_a_stage_of_zero_steps_stores_no_loss(stage_scene: Scene, tmp_path: Path) -> None:
    cfg = stage_smoke_cfg(decouple={"steps": 0})
    artifact = _run("decouple", stage_scene, {}, cfg, tmp_path)
    metrics = artifact.meta["metrics"]
    assert (metrics["steps"], metrics["initial_loss"], metrics["final_loss"]) == (0, None, None)
    write_artifact_files(tmp_path, artifact)
    assert '"final_loss": null' in (tmp_path / "meta.json").read_text()


def test_non_finite_loss_stops_the_stage(
    stage_scene: Scene, stage_decoupled: Artifact, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []

    def nan_at_sixth_step(preds, targets, ssim_weight):
        calls.append(1)
        loss = photometric_loss(preds, targets, ssim_weight)
        return loss * float("nan") if len(calls) == 6 else loss

    monkeypatch.setattr(relay_module, "photometric_loss", nan_at_sixth_step)
    with refused(DivergenceError, "'relay'", "step 6", "'loss'"):
        SPECS["relay"].run(stage_scene, {"decouple": stage_decoupled}, stage_smoke_cfg())


def test_sinks_receive_live_metrics(stage_scene: Scene, stage_relayed: Artifact) -> None:
    records = []

    def sink(stage: str, step: int, scalars, images=None) -> None:
        records.append((stage, step, dict(scalars), images))

    cfg = stage_smoke_cfg(train={"log_every": 4, "image_every": 8}, deform={"steps": 8})
    log.add_sink(sink)
    try:
        deformed = SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, cfg)
    finally:
        log.remove_sink(sink)
    assert [step for _, step, _, _ in records] == [4, 8]
    assert deformed.meta["logged_scalars"] == [[step, scalars] for _, step, scalars, _ in records]
    stage, _, scalars, images = records[-1]
    assert stage == "deform"
    for key in ("loss", "psnr", "num_bg", "num_fg", "fg_fraction", "lr/fg.means", "lr/grid"):
        assert key in scalars, key
    assert 0.0 < scalars["fg_fraction"] < 1.0
    assert records[0][3] is None
    assert images["render"].shape == images["target"].shape == (27, 48, 3)


def test_a_resumed_run_sends_its_sinks_the_records_from_before_the_kill(
    stage_scene: Scene, tmp_path: Path
) -> None:
    # a resumed job's TensorBoard would otherwise start its curves at the checkpoint
    cfg = stage_smoke_cfg(train={"checkpoint_every": 2, "log_every": 1}, decouple={"steps": 6})
    with pytest.raises(KilledError):
        _run("decouple", stage_scene, {}, cfg, tmp_path, kill_at=5)
    records = []

    def sink(stage: str, step: int, scalars, images=None) -> None:
        records.append((stage, step))

    log.add_sink(sink)
    try:
        resumed = _run("decouple", stage_scene, {}, cfg, tmp_path)
    finally:
        log.remove_sink(sink)
    assert resumed.meta["metrics"]["resumed_from"] == 4
    assert records == [("decouple", step) for step in range(1, 7)]
    assert [step for step, _ in resumed.meta["logged_scalars"]] == list(range(1, 7))


def test_a_checkpoint_from_before_scalars_were_kept_still_resumes(
    stage_scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # an in-stage checkpoint written by an older relaygs holds no "history"
    cfg = stage_smoke_cfg(train={"checkpoint_every": 2, "log_every": 1}, decouple={"steps": 6})
    with pytest.raises(KilledError):
        _run("decouple", stage_scene, {}, cfg, tmp_path, kill_at=5)
    real_load = StageCheckpointer.load

    def load_an_older_checkpoint(self):
        state = real_load(self)
        del state.extras["history"]
        return state

    monkeypatch.setattr(StageCheckpointer, "load", load_an_older_checkpoint)
    resumed = _run("decouple", stage_scene, {}, cfg, tmp_path)
    assert resumed.meta["metrics"]["resumed_from"] == 4
    assert [step for step, _ in logged_scalars(resumed)] == [5, 6]


def test_an_artifact_stored_before_scalars_were_kept_has_none() -> None:
    assert logged_scalars(Artifact("decouple", {}, {"metrics": {}})) == []


def test_resumed_run_counts_the_seconds_before_the_kill(
    stage_scene: Scene, tmp_path: Path, capsys
) -> None:
    cfg = stage_smoke_cfg(train={"checkpoint_every": 2, "log_every": 1}, decouple={"steps": 6})
    with pytest.raises(KilledError):
        _run("decouple", stage_scene, {}, cfg, tmp_path, kill_at=3)
    state = StageCheckpointer(tmp_path, "decouple", KEY, 2).load()
    assert state is not None and state.step == 2
    before_kill = float(state.extras["seconds"])
    assert before_kill > 0.0
    capsys.readouterr()
    context = BuildContext(tmp_path, "decouple", KEY)
    with building(context):
        metrics = SPECS["decouple"].run(stage_scene, {}, cfg).meta["metrics"]
    assert context.earlier_seconds == before_kill  # the store adds them to the build's time
    assert capsys.readouterr().out == (
        f"[decouple] resuming from the checkpoint of step 2 of 6 ({before_kill:.1f} s of "
        "training before it)\n"
    )
    assert metrics["resumed_from"] == 2
    # steps_per_second covers only this run's steps, so it gives this run's seconds back.
    this_run = (metrics["steps"] - 2) / metrics["steps_per_second"]
    assert metrics["train_seconds"] >= before_kill
    assert metrics["train_seconds"] == pytest.approx(before_kill + this_run, rel=1e-9)


def test_photometric_loss_is_l1_plus_weighted_d_ssim_and_zero_on_a_match() -> None:
    generator = torch.Generator().manual_seed(0)
    target = torch.rand(16, 20, 3, generator=generator)
    pred = target * 0.5
    assert float(photometric_loss([target], [target], 0.2)) == pytest.approx(0.0, abs=1e-6)
    l1 = float((pred - target).abs().mean())
    d_ssim = 1.0 - float(ssim(pred, target))
    assert 0.0 < d_ssim < 1.0
    # mean over two views: the mismatched one and an exact match (loss 0)
    loss = photometric_loss([pred, target], [target, target], 0.2)
    assert float(loss) == pytest.approx((l1 + 0.2 * d_ssim) / 2, rel=1e-5)
    assert float(photometric_loss([pred], [target], 0.0)) == pytest.approx(l1, rel=1e-6)


def test_batch_psnr_clamps_renders_to_the_displayable_range() -> None:
    target = torch.full((4, 5, 3), 0.5)
    over = torch.full((4, 5, 3), 1.5)  # shown as 1.0: squared error 0.25 -> 10·log10(4) dB
    assert batch_psnr([over], [target]) == pytest.approx(10 * math.log10(4.0), rel=1e-5)


def test_kept_scalars_leave_out_values_json_cannot_hold() -> None:
    # a view rendered exactly has an infinite PSNR; artifact meta and checkpoints are JSON
    history = ScalarHistory()
    history.add(3, {"loss": 0.0, "psnr": math.inf, "fg_fraction": math.nan, "lr/grid": 1e-3})
    assert history.state() == [[3, {"loss": 0.0, "lr/grid": 1e-3}]]
    json.dumps(history.state(), allow_nan=False)
    restored = ScalarHistory()
    restored.load_state(json.loads(json.dumps(history.state())))
    assert restored.records == history.records


def test_steps_read_their_loss_from_the_device_only_when_they_log(
    stage_scene: Scene, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a GPU a read waits for every queued kernel; the loss tracker keeps losses on the
    device, so the reads of a run grow with its logged steps, not with its steps."""
    reads: list[str] = []
    for name in ("__float__", "item", "tolist"):
        original = getattr(torch.Tensor, name)

        def counted(self, *args, _original=original, _name=name, **kwargs):
            reads.append(_name)
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(torch.Tensor, name, counted)
    counts = []
    for steps in (6, 12):
        cfg = stage_smoke_cfg(
            decouple={"steps": steps, "densify": {"densify_until": 0, "opacity_reset_every": 0}},
            train={"log_every": 1000, "checkpoint_every": 1000},
        )
        reads.clear()
        artifact = _run("decouple", stage_scene, {}, cfg, tmp_path / str(steps))
        counts.append(len(reads))
        assert artifact.meta["metrics"]["final_loss"] > 0
    assert counts[0] == counts[1], counts
