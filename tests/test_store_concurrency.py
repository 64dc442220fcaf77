"""Several processes and killed processes: one build per key, and no half artifacts."""

import os
import signal
import time
from pathlib import Path

import torch

from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.store import ArtifactStore
from store_helpers import CountingBuild, spawn, wait_until

KEY = artifact_key("decouple", 1, {"case": "concurrency"}, "scene", [])


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


def test_two_processes_needing_the_same_missing_artifact_build_it_once(tmp_path):
    counter, started = tmp_path / "builds.txt", tmp_path / "started"
    procs = [
        spawn("test_store_concurrency", "child_build", tmp_path / "store", counter, started, 1.0)
        for _ in range(2)
    ]
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
    proc = spawn("test_store_concurrency", "child_build", store.root, counter, started, 60.0)
    wait_until(started.exists, proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not store.has("decouple", KEY) and store.list() == []
    assert not (store.root / "decouple" / KEY).exists()

    artifact, info = store.get_or_build("decouple", KEY, CountingBuild(), config={}, lineage=[])
    assert not info.cache_hit and artifact.meta["calls"] == 1
    assert store.verify() == []
