"""Several processes and killed processes: one build per key, and no half artifacts."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import torch

from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.store import ArtifactStore

KEY = artifact_key("decouple", 1, {"case": "concurrency"}, "scene", [])
TESTS_DIR = Path(__file__).resolve().parent


def child_build(root: str, counter: str, started: str, sleep_s: float) -> None:
    """Run in a child process: get_or_build with a slow build that logs each real run."""

    def build():
        Path(started).touch()
        with open(counter, "a") as handle:
            handle.write(f"{os.getpid()}\n")
        time.sleep(float(sleep_s))
        return Artifact("decouple", {"x": torch.arange(6)}, {"pid": os.getpid()})

    _, info = ArtifactStore(root).get_or_build(
        "decouple", KEY, build, config={"case": "concurrency"}, lineage=[]
    )
    print("hit" if info.cache_hit else "built")


def _spawn(*args) -> subprocess.Popen:
    code = (
        f"import sys; sys.path.insert(0, {str(TESTS_DIR)!r}); "
        f"import test_store_concurrency as t; t.child_build(*{[str(a) for a in args]!r})"
    )
    return subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def _wait_for(path: Path, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


def test_two_processes_needing_the_same_missing_artifact_build_it_once(tmp_path):
    counter, started = tmp_path / "builds.txt", tmp_path / "started"
    procs = [_spawn(tmp_path / "store", counter, started, 1.0) for _ in range(2)]
    outputs = [proc.communicate(timeout=120) for proc in procs]
    assert [proc.returncode for proc in procs] == [0, 0], [err for _, err in outputs]
    assert sorted(out.strip() for out, _ in outputs) == ["built", "hit"]
    builders = counter.read_text().split()
    assert len(builders) == 1
    artifact = ArtifactStore(tmp_path / "store").load("decouple", KEY)
    assert artifact.meta["pid"] == int(builders[0])


def test_a_build_killed_with_sigkill_leaves_no_artifact_and_the_next_run_builds(tmp_path):
    store = ArtifactStore(tmp_path / "store")
    counter, started = tmp_path / "builds.txt", tmp_path / "started"
    proc = _spawn(store.root, counter, started, 60.0)
    _wait_for(started)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not store.has("decouple", KEY) and store.list() == []
    assert not (store.root / "decouple" / KEY).exists()

    artifact, info = store.get_or_build(
        "decouple",
        KEY,
        lambda: Artifact("decouple", {"x": torch.arange(6)}, {}),
        config={},
        lineage=[],
    )
    assert not info.cache_hit and torch.equal(artifact.tensors["x"], torch.arange(6))
    assert store.verify() == []
