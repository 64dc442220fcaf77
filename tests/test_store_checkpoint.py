"""In-stage checkpoints: exact resume (params, Adam state, RNG) in-process and after SIGKILL."""

import json
import os
import random
import signal
import time

import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.errors import DivergenceError
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.checkpoint import STATE_FILE, StageCheckpointer
from relaygs.pipeline.context import current_build
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.layout import TENSORS_FILE
from relaygs.pipeline.statecodec import decode_tree, encode_tree
from relaygs.pipeline.store import ArtifactStore
from store_helpers import flip_last_byte, sealed, spawn, wait_until

KEY = artifact_key("train", 1, {"case": "resume"}, "scene", [])


def _seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)


def _one_step(param, optimizer):
    """A step that draws from torch, numpy and python RNGs, so each must be restored."""
    noise = torch.randn(param.shape)
    scale = float(np.random.uniform(0.5, 1.5)) * random.uniform(0.5, 1.5)
    loss = ((param - noise) ** 2).sum() * scale
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()


def train(ckpt: StageCheckpointer | None, total_steps: int, step_sleep=0.0, log=lambda line: None):
    """Adam on a small tensor against random targets, resuming from `ckpt` when it has one."""
    _seed_everything(0)
    param = torch.nn.Parameter(torch.randn(32))
    optimizer = torch.optim.Adam([param], lr=0.05)
    start = 0
    state = ckpt.load() if ckpt is not None else None
    if state is not None:
        with torch.no_grad():
            param.copy_(state.tensors["param"])
        optimizer.load_state_dict(state.optimizers["adam"])
        state.restore_rng()
        start = state.step
        assert state.extras == {"note": "resume", "loss_history": [start]}
    log(f"start {start}")
    for step in range(start, total_steps):
        _one_step(param, optimizer)
        time.sleep(step_sleep)
        if ckpt is not None and ckpt.due(step + 1):
            extras = {"note": "resume", "loss_history": [step + 1]}
            ckpt.save(step + 1, {"param": param}, {"adam": optimizer}, extras)
    return param.detach().clone(), start


def child_train(root: str, total_steps: str, every: str, step_sleep: str, log_path: str) -> None:
    """Run in a child process: train inside get_or_build, checkpointing through the context."""

    def log(line):
        with open(log_path, "a") as handle:
            handle.write(line + "\n")

    def build():
        ckpt = current_build().checkpointer(int(every))
        param, start = train(ckpt, int(total_steps), float(step_sleep), log)
        return Artifact("train", {"param": param}, {"resumed_from": start})

    ArtifactStore(root).get_or_build("train", KEY, build, config={"case": "resume"}, lineage=[])


def test_resume_from_a_checkpoint_is_bitwise_identical_with_its_rng_states_only(tmp_path):
    reference, _ = train(None, total_steps=12)
    ckpt = StageCheckpointer(tmp_path, "train", KEY, every_n_steps=5)
    train(ckpt, total_steps=7)  # stops after step 7; the last checkpoint is step 5
    state = ckpt.load()
    param = torch.nn.Parameter(state.tensors["param"].clone())
    optimizer = torch.optim.Adam([param], lr=0.05)
    optimizer.load_state_dict(state.optimizers["adam"])
    _seed_everything(123)  # a fresh process would start from other RNG states
    for _ in range(5, 12):  # without restoring the RNG states: another result
        _one_step(param, optimizer)
    assert not torch.equal(param.detach(), reference)
    resumed, start = train(ckpt, total_steps=12)
    assert start == 5
    assert torch.equal(resumed, reference)
    assert [step for step in range(1, 12) if ckpt.due(step)] == [5, 10]
    assert [ckpt.latest_due(step) for step in (0, 4, 5, 9, 10, 11)] == [0, 0, 5, 5, 10, 10]


@pytest.mark.parametrize(
    ("damage", "warned"),
    [
        (lambda folder: flip_last_byte(folder / TENSORS_FILE), "damaged checkpoint"),
        (sealed(STATE_FILE, json.dumps({"step": 4})), "unreadable checkpoint"),  # no tensors...
        # safetensors' own SafetensorError escaped as a traceback
        (sealed(TENSORS_FILE, "junk"), "unreadable checkpoint"),
    ],
)
def test_only_the_newest_checkpoints_are_kept_and_damage_falls_back(tmp_path, damage, warned):
    ckpt = StageCheckpointer(tmp_path, "train", KEY, every_n_steps=2, keep_last=2)
    for step in (2, 4, 6):
        ckpt.save(step, {"x": torch.full((3,), float(step))})
    steps = sorted(p.name for p in ckpt.folder.iterdir())
    assert steps == ["step-000000000004", "step-000000000006"]
    damage(ckpt.folder / "step-000000000006")
    with pytest.warns(UserWarning, match=warned):
        state = ckpt.load()
    assert state.step == 4 and torch.equal(state.tensors["x"], torch.full((3,), 4.0))


def test_a_non_finite_optimizer_moment_stops_the_stage_before_anything_is_written(tmp_path):
    ckpt = StageCheckpointer(tmp_path, "relay", KEY, every_n_steps=2)
    param = torch.nn.Parameter(torch.ones(4))
    optimizer = torch.optim.Adam([param], lr=0.1)
    param.grad = torch.full((4,), 2.0)
    optimizer.step()
    ckpt.save(2, {"param": param}, {"adam": optimizer})  # finite: written
    optimizer.state[param]["exp_avg_sq"][1] = float("inf")  # a squared gradient overflowed
    moment = "optimizers['adam']['state'][0]['exp_avg_sq']"
    with refused(DivergenceError, "'relay'", "step 4", moment):
        ckpt.save(4, {"param": param}, {"adam": optimizer})
    assert [path.name for path in ckpt.folder.iterdir()] == ["step-000000000002"]
    with refused(DivergenceError, "extras['history'][1]"):
        ckpt.save(4, {"param": param}, None, {"history": [torch.zeros(2), torch.tensor(np.nan)]})


def test_state_codec_roundtrips_nested_state_exactly():
    tree = {
        "state": {0: {"step": torch.tensor(3.0), "exp_avg": torch.arange(4.0)}},
        "groups": [{"betas": (0.9, 0.999), "params": [0], "foreach": None, "lr": 1e-3}],
        "rng": ("MT", np.arange(5, dtype=np.uint32), 3, 0.1),
        (1, "a"): [np.float32(0.25), float("inf")],
    }
    tensors = {}
    skeleton = encode_tree(tree, tensors, "t.", "tree")
    decoded = decode_tree(json.loads(json.dumps(skeleton)), tensors)
    assert decoded["groups"] == tree["groups"]
    assert torch.equal(decoded["state"][0]["exp_avg"], tree["state"][0]["exp_avg"])
    assert decoded["rng"][1].dtype == np.uint32 and list(decoded["rng"][1]) == list(range(5))
    assert decoded[(1, "a")] == [0.25, float("inf")]
    with pytest.raises(TypeError, match="cannot checkpoint a object"):
        encode_tree({"x": object()}, {}, "t.", "tree")


def test_a_run_killed_with_sigkill_resumes_from_its_checkpoint(tmp_path):
    store = ArtifactStore(tmp_path / "store")
    log = tmp_path / "log.txt"
    total, every = 60, 5
    proc = spawn("test_store_checkpoint", "child_train", store.root, total, every, 0.03, log)
    ckpt_dir = store.root / "train" / f"{KEY}.ckpt"
    wait_until(lambda: ckpt_dir.is_dir() and any(ckpt_dir.glob("step-*")), proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert not store.has("train", KEY)

    rerun = spawn("test_store_checkpoint", "child_train", store.root, total, every, 0.0, log)
    _, err = rerun.communicate(timeout=120)
    assert rerun.returncode == 0, err
    starts = [int(line.split()[1]) for line in log.read_text().splitlines() if "start" in line]
    assert starts[0] == 0 and len(starts) == 2
    assert 0 < starts[1] < total and starts[1] % every == 0
    artifact = store.load("train", KEY)
    assert artifact.meta == {"resumed_from": starts[1]}
    reference, _ = train(None, total_steps=total)
    assert torch.equal(artifact.tensors["param"], reference)
    assert not ckpt_dir.exists()
