"""What the store tests share: keys, a counting build, child processes, and damage that the
hashes do not catch (bytes broken before they were sealed)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.integrity import file_sha256, seal
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.store import ArtifactStore

KEY = artifact_key("decouple", 1, {"steps": 3}, "scene", [])
OTHER = artifact_key("decouple", 1, {"steps": 4}, "scene", [])
TESTS_DIR = Path(__file__).resolve().parent


class CountingBuild:
    """A build of arange tensors (plus `offset`) that counts how often it really ran."""

    def __init__(self, stage: str = "decouple", offset: float = 0.0) -> None:
        self.stage, self.offset, self.calls = stage, offset, 0

    def __call__(self) -> Artifact:
        self.calls += 1
        tensors = {"xyz": torch.arange(12.0).reshape(4, 3) + self.offset, "mask": torch.ones(4) > 0}
        return Artifact(self.stage, tensors, {"metrics": {"loss": 0.5}, "calls": self.calls})


def store_with(root: Path, *keys: str) -> ArtifactStore:
    """A store at `root` holding a finished decouple artifact under each of `keys`."""
    store = ArtifactStore(root)
    for key in keys:
        store.get_or_build("decouple", key, CountingBuild(), config={}, lineage=[])
    return store


def spawn(module: str, function: str, *args: object) -> subprocess.Popen:
    """`function(*args)` of tests/`module`.py (arguments as strings) in a child Python."""
    code = (
        f"import sys; sys.path.insert(0, {str(TESTS_DIR)!r}); "
        f"from {module} import {function}; {function}(*{[str(a) for a in args]!r})"
    )
    return subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def wait_until(ready: Callable[[], bool], child: subprocess.Popen, timeout_s: float = 90) -> None:
    """Poll until `ready()`, failing if `child` ends or `timeout_s` passes first."""
    deadline = time.monotonic() + timeout_s
    while not ready():
        assert time.monotonic() < deadline and child.poll() is None, "the child never got there"
        time.sleep(0.02)


def flip_last_byte(path: Path) -> None:
    """Damage a file the way a bad disk would: one changed byte, its recorded hash unchanged."""
    data = bytearray(path.read_bytes())
    data[-1] ^= 0xFF
    path.write_bytes(bytes(data))


def sealed(name: str, text: str) -> Callable[[Path], None]:
    """Damage that writes `text` to a folder's file `name` and seals the folder again."""
    return lambda folder: ((folder / name).write_text(text), seal(folder))


def damage_dtype_and_rehash(folder: Path) -> None:
    """Turn the first F32 tensor of `folder`'s safetensors into F64 (its bytes then no longer
    fit its shape), and record the new bytes' hashes in the manifest and the marker."""
    tensors = folder / "tensors.safetensors"
    tensors.write_bytes(tensors.read_bytes().replace(b'"F32"', b'"F64"', 1))
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"]["tensors.safetensors"]["sha256"] = file_sha256(tensors)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    seal(folder)
