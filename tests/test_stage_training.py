"""Training loop contracts: resume equals an uninterrupted run, divergence stops and writes
nothing, live metrics reach the log sinks."""

from __future__ import annotations

import json
import math
import re
import shutil
from functools import partial
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
    """A log sink that raises `error` at step `step_to_die`, as a kill (or Ctrl-C) would."""

    def sink(stage: str, step: int, scalars, images=None) -> None:
        if step == step_to_die:
            raise error(f"{stage} killed at {step}")

    return sink


def _recorder(records: list):
    """A log sink that appends each record it receives to `records`."""
    return lambda stage, step, scalars, images=None: records.append(
        (stage, step, dict(scalars), images)
    )


def _run(stage: str, scene: Scene, upstream: dict, cfg: dict, root: Path, sink=None, context=None):
    """Run `stage` as the build of KEY in the store at `root`, `sink` receiving its logs."""
    if sink is not None:
        log.add_sink(sink)
    try:
        with building(context or BuildContext(root, stage, KEY)):
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
    """Ctrl-C names the step and the checkpoint a rerun resumes from, which ends bitwise equal
    (docs/artifacts.md); the relay's frozen-background cache starts empty on resume."""
    upstreams = {
        "decouple": {},
        "relay": {"decouple": stage_decoupled},
        "deform": {"relay": stage_relayed},
    }
    upstream = upstreams[stage]
    # checkpoints every 5 steps, densification every 4: the resume restores changed shapes
    cfg = stage_smoke_cfg(train={"checkpoint_every": 5, "log_every": 1})
    whole = _run(stage, stage_scene, upstream, cfg, tmp_path / "a")
    steps = cfg[stage]["steps"]
    with refused(Interrupted, stage, f"step 12 of {steps}", "step 10") as caught:
        _run(stage, stage_scene, upstream, cfg, tmp_path / "b", _kill_at(13, KeyboardInterrupt))
    assert isinstance(caught.value, KeyboardInterrupt)
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


def test_divergence_names_stage_step_tensor_and_stores_nothing(
    stage_scene: Scene, tmp_path: Path
) -> None:
    store = ArtifactStore(tmp_path)
    cfg = stage_smoke_cfg(decouple={"lr": {"sh_dc": 1e36}}, train={"checkpoint_every": 1})
    build = partial(SPECS["decouple"].run, stage_scene, {}, cfg)
    with refused(DivergenceError, "'decouple'", "diverged at step", "tensor '") as caught:
        store.get_or_build("decouple", KEY, build, config={}, lineage=[])
    step = int(re.search(r"step (\d+)", str(caught.value)).group(1))
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


def test_sinks_receive_live_metrics(
    stage_scene: Scene, stage_relayed: Artifact, tmp_path: Path
) -> None:
    records = []
    cfg = stage_smoke_cfg(train={"log_every": 4, "image_every": 8}, deform={"steps": 8})
    upstream = {"relay": stage_relayed}
    deformed = _run("deform", stage_scene, upstream, cfg, tmp_path, _recorder(records))
    assert [step for _, step, _, _ in records] == [4, 8]
    assert deformed.meta["logged_scalars"] == [[step, scalars] for _, step, scalars, _ in records]
    stage, _, scalars, images = records[-1]
    assert stage == "deform"
    for key in ("loss", "psnr", "num_bg", "num_fg", "fg_fraction", "lr/fg.means", "lr/grid"):
        assert key in scalars, key
    assert 0.0 < scalars["fg_fraction"] < 1.0
    assert records[0][3] is None
    assert images["render"].shape == images["target"].shape == (27, 48, 3)


def test_a_resumed_run_counts_and_replays_what_came_before_the_kill(
    stage_scene: Scene, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The seconds before the kill count in its build time, and its sinks get the records from
    before it (a resumed job's TensorBoard would otherwise start its curves at the checkpoint)."""
    cfg = stage_smoke_cfg(train={"checkpoint_every": 2, "log_every": 1}, decouple={"steps": 6})
    with pytest.raises(KilledError):
        _run("decouple", stage_scene, {}, cfg, tmp_path / "a", _kill_at(5))
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    state = StageCheckpointer(tmp_path / "a", "decouple", KEY, 2).load()
    assert state is not None and state.step == 4
    before_kill = float(state.extras["seconds"])
    assert before_kill > 0.0
    records = []
    capsys.readouterr()
    context = BuildContext(tmp_path / "a", "decouple", KEY)
    resumed = _run("decouple", stage_scene, {}, cfg, tmp_path, _recorder(records), context)
    assert [record[:2] for record in records] == [("decouple", step) for step in range(1, 7)]
    assert [step for step, _ in resumed.meta["logged_scalars"]] == list(range(1, 7))
    assert context.earlier_seconds == before_kill  # the store adds them to the build's time
    assert capsys.readouterr().out == (
        f"[decouple] resuming from the checkpoint of step 4 of 6 ({before_kill:.1f} s of "
        "training before it)\n"
    )
    metrics = resumed.meta["metrics"]
    assert metrics["resumed_from"] == 4
    # steps_per_second covers only this run's steps, so it gives this run's seconds back.
    this_run = (metrics["steps"] - 4) / metrics["steps_per_second"]
    assert metrics["train_seconds"] >= before_kill
    assert metrics["train_seconds"] == pytest.approx(before_kill + this_run, rel=1e-9)
    # an in-stage checkpoint written by an older relaygs holds no "history"
    real_load = StageCheckpointer.load

    def load_an_older_checkpoint(self):
        state = real_load(self)
        del state.extras["history"]
        return state

    monkeypatch.setattr(StageCheckpointer, "load", load_an_older_checkpoint)
    older = _run("decouple", stage_scene, {}, cfg, tmp_path / "b")
    assert older.meta["metrics"]["resumed_from"] == 4
    assert [step for step, _ in logged_scalars(older)] == [5, 6]
    assert logged_scalars(Artifact("decouple", {}, {"metrics": {}})) == []  # an older artifact


def test_photometric_loss_is_l1_plus_weighted_d_ssim_and_psnr_clamps_to_what_is_shown() -> None:
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
    # batch_psnr clamps renders to the displayable range
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
