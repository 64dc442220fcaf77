"""Kills at the store's fragile moments, injected at the exact call instead of by timing: after
an artifact is published but before its checkpoints are deleted, and half-way through gc."""

import errno

import pytest
import torch
from safetensors import SafetensorError

from relaygs.pipeline import fsio as fsio_module
from relaygs.pipeline import gc as gc_module
from relaygs.pipeline import store as store_module
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.context import current_build
from relaygs.pipeline.store import ArtifactStore
from store_helpers import KEY, OTHER, store_with


class KilledError(BaseException):
    """Stands in for SIGKILL (or SIGTERM's KeyboardInterrupt) at the injected point."""


def _checkpointing_build():
    current_build().checkpointer(1).save(1, {"x": torch.ones(2)})
    return Artifact("decouple", {"x": torch.ones(2)}, {})


def _not_called():
    raise AssertionError("a finished artifact was built again")


def test_checkpoints_left_by_a_kill_after_publishing_are_removed_by_the_next_request(
    tmp_path, monkeypatch
):
    store = ArtifactStore(tmp_path)
    ckpt = store.root / "decouple" / f"{KEY}.ckpt"
    real_remove = store_module.remove_tree

    def killed_before_clearing(path):
        if path == ckpt:
            raise KilledError
        real_remove(path)

    monkeypatch.setattr(store_module, "remove_tree", killed_before_clearing)
    with pytest.raises(KilledError):
        store.get_or_build("decouple", KEY, _checkpointing_build, config={}, lineage=[])
    monkeypatch.setattr(store_module, "remove_tree", real_remove)
    assert store.has("decouple", KEY) and ckpt.is_dir()  # published, checkpoints still there
    _, info = store.get_or_build("decouple", KEY, _not_called, config={}, lineage=[])
    assert info.cache_hit
    assert not ckpt.exists(), "a finished artifact's checkpoints outlived the rerun"


def test_a_gc_killed_while_removing_an_artifact_leaves_no_damaged_folder(tmp_path, monkeypatch):
    store = store_with(tmp_path, KEY, OTHER)
    real_remove = gc_module.remove_tree

    def killed_half_way(path):  # rmtree had deleted one file when the kill came
        (path / "tensors.safetensors").unlink()
        raise KilledError

    monkeypatch.setattr(gc_module, "remove_tree", killed_half_way)
    with pytest.raises(KilledError):
        store.gc(keep={KEY})
    monkeypatch.setattr(gc_module, "remove_tree", real_remove)
    assert store.verify() == [] and store.damaged() == []
    assert [item.key for item in store.list()] == [KEY]
    store.gc()
    assert sorted(p.name for p in (store.root / "decouple").iterdir()) == [KEY]


@pytest.mark.parametrize("failing_write", [1, 2], ids=["checkpoint", "artifact"])
def test_a_full_disk_mid_build_leaves_no_partial_artifact_and_keeps_earlier_ones(
    tmp_path, monkeypatch, failing_write
):
    store = store_with(tmp_path, OTHER)
    real_save, writes = fsio_module.save_file, []

    def full_on_write(tensors, path):
        writes.append(path)
        if len(writes) == failing_write:  # safetensors reports I/O failures in its own type
            raise SafetensorError("Error while serializing: I/O error: No space left (os error 28)")
        real_save(tensors, path)

    monkeypatch.setattr(fsio_module, "save_file", full_on_write)
    with pytest.raises(OSError) as raised:
        store.get_or_build("decouple", KEY, _checkpointing_build, config={}, lineage=[])
    assert (raised.value.errno, raised.value.filename) == (errno.ENOSPC, writes[-1])
    assert not store.has("decouple", KEY) and store.verify() == []
    assert not list((store.root / "decouple").glob(f".tmp-{KEY}-*"))
    assert store.has("decouple", OTHER)
    monkeypatch.setattr(fsio_module, "save_file", real_save)  # space freed: the rerun completes
    artifact, _ = store.get_or_build("decouple", KEY, _checkpointing_build, config={}, lineage=[])
    assert torch.equal(artifact.tensors["x"], torch.ones(2)) and store.verify() == []
