"""Another process's gc or build acting on the store between two steps of this one, forced at
the exact call (its work runs inside a patched hook), not left to timing."""

import fcntl

import pytest
from filelock import FileLock, Timeout

from refusals import refused
from relaygs.pipeline import gc as gc_module
from relaygs.pipeline import integrity as integrity_module
from relaygs.pipeline import store as store_module
from relaygs.pipeline.fsio import remove_tree
from relaygs.pipeline.store import ArtifactChangedError, ArtifactStore
from store_helpers import KEY, OTHER, CountingBuild, flip_last_byte, store_with


def _after_running(other_process, action, then=False):
    """`action`, whose first call first lets `other_process` act on the store (with `then`,
    once it returned)."""
    calls = []

    def wrapper(*args, **kwargs):
        calls.append(args)
        if len(calls) == 1 and not then:
            other_process()
        result = action(*args, **kwargs)
        if len(calls) == 1 and then:
            other_process()
        return result

    return wrapper


@pytest.mark.parametrize("entry", ["unkept artifact", "incomplete folder", "checkpoints"])
def test_gc_passes_over_an_entry_another_process_removed_after_gc_listed_it(
    tmp_path, monkeypatch, entry
):
    store = store_with(tmp_path, KEY, OTHER)
    stage_dir = store.root / "decouple"
    path, keep = {
        "unkept artifact": (stage_dir / OTHER, {KEY}),
        "incomplete folder": (stage_dir / ("a" * 64), None),
        "checkpoints": (stage_dir / f"{KEY}.ckpt", None),
    }[entry]
    path.mkdir(exist_ok=True)
    real_is_garbage = gc_module._is_garbage

    def another_gc_gets_there_first(candidate, key, kept):
        garbage = real_is_garbage(candidate, key, kept)
        if garbage and candidate == path:
            remove_tree(path)  # a second gc, or a build clearing its checkpoints, under the lock
        return garbage

    monkeypatch.setattr(gc_module, "_is_garbage", another_gc_gets_there_first)
    report = store.gc(keep=keep)
    assert not path.exists() and path not in report.removed
    assert store.has("decouple", KEY) and store.verify() == []


def test_gc_keeps_an_incomplete_folder_whose_build_finished_after_gc_listed_it(
    tmp_path, monkeypatch
):
    store = store_with(tmp_path, KEY)
    path = store.root / "decouple" / OTHER
    path.mkdir()  # OTHER's build is under way in another process, its folder not sealed yet
    real_is_garbage = gc_module._is_garbage

    def the_build_finishes_before_gc_locks_it(candidate, key, kept):
        garbage = real_is_garbage(candidate, key, kept)
        if garbage and candidate == path and not store.has("decouple", OTHER):
            store.get_or_build("decouple", OTHER, CountingBuild(), config={}, lineage=[])
        return garbage

    monkeypatch.setattr(gc_module, "_is_garbage", the_build_finishes_before_gc_locks_it)
    report = store.gc()
    assert path not in report.removed
    assert store.has("decouple", OTHER) and store.verify() == []


@pytest.mark.parametrize("command", ["verify", "ls"])
def test_an_artifact_gc_removes_while_it_is_read_is_not_reported_damaged(
    tmp_path, monkeypatch, command
):
    store = store_with(tmp_path, KEY, OTHER)
    assert OTHER < KEY  # so OTHER's folder is the first read, and the hook removes it then

    def gc_removes_other():
        store.gc(keep={KEY})

    if command == "verify":  # removed half-way through hashing the files of the first folder
        hook = _after_running(gc_removes_other, integrity_module.file_sha256)
        monkeypatch.setattr(integrity_module, "file_sha256", hook)
        problems = store.verify()
    else:  # removed between seeing the first folder's marker and reading its manifest
        hook = _after_running(gc_removes_other, store_module.read_own_manifest)
        monkeypatch.setattr(store_module, "read_own_manifest", hook)
        problems = store.damaged()
    assert problems == []
    assert [item.key for item in store.list()] == [KEY]


def test_a_damaged_artifact_a_rebuild_replaces_while_verify_reads_it_is_checked_again(
    tmp_path, monkeypatch
):
    store = store_with(tmp_path, KEY)
    tensors = store.path("decouple", KEY) / "tensors.safetensors"
    flip_last_byte(tensors)  # damaged: verify would report it
    real_sha256 = integrity_module.file_sha256
    rebuilt = []

    def a_rebuild_replaces_it_once_read(path):
        digest = real_sha256(path)
        if path == tensors and not rebuilt:  # the damaged bytes are read, not yet reported
            rebuilt.append(True)
            store.get_or_build("decouple", KEY, CountingBuild(), config={}, lineage=[])
        return digest

    monkeypatch.setattr(integrity_module, "file_sha256", a_rebuild_replaces_it_once_read)
    assert store.verify() == []  # what it reports is the folder now there, which is sound
    assert rebuilt


@pytest.mark.parametrize("verify", [True, False])
def test_a_load_gc_cuts_short_says_so_rather_than_calling_it_corrupt(tmp_path, monkeypatch, verify):
    # `artifacts eval KEY` while another shell runs `artifacts gc`: before, "unreadable artifact
    # files", which sends the user looking for a damaged disk
    store = store_with(tmp_path, KEY, OTHER)
    hook = _after_running(lambda: store.gc(keep={KEY}), store_module.read_artifact_files)
    monkeypatch.setattr(store_module, "read_artifact_files", hook)
    with refused(ArtifactChangedError, str(store.path("decouple", OTHER)), "another process"):
        store.load("decouple", OTHER, verify=verify)


def test_a_hit_published_after_it_was_looked_for_and_cut_short_is_not_corrupt(
    tmp_path, monkeypatch
):
    # a build beside this one publishes the folder just after this one found none, and a gc
    # removes it while this one reads it: not on_corrupt=error's "corrupt", but asked again
    store = store_with(tmp_path, KEY, OTHER)
    real_identity = store_module.folder_identity
    looks = []

    def not_there_at_first(folder):
        looks.append(folder)
        return None if len(looks) == 1 else real_identity(folder)

    monkeypatch.setattr(store_module, "folder_identity", not_there_at_first)
    hook = _after_running(lambda: store.gc(keep={KEY}), store_module.read_artifact_files)
    monkeypatch.setattr(store_module, "read_artifact_files", hook)
    build = CountingBuild()
    artifact, info = store.get_or_build(
        "decouple", OTHER, build, config={}, lineage=[], on_corrupt="error"
    )
    assert info.cache_hit and build.calls == 0  # read again under its lock: gc left it be
    assert artifact.meta["calls"] == 1


@pytest.mark.parametrize("on_corrupt", ["rebuild", "error"])
@pytest.mark.parametrize("moment", ["after it was found", "while it was hashed"])
def test_a_cache_hit_gc_removes_before_it_is_loaded_is_built_again(
    tmp_path, monkeypatch, moment, on_corrupt
):
    store = store_with(tmp_path, KEY, OTHER)

    def gc_removes_other():
        store.gc(keep={KEY})

    if moment == "after it was found":
        monkeypatch.setattr(store, "has", _after_running(gc_removes_other, store.has, then=True))
    else:
        hook = _after_running(gc_removes_other, integrity_module.file_sha256)
        monkeypatch.setattr(integrity_module, "file_sha256", hook)
    build = CountingBuild()
    artifact, info = store.get_or_build(
        "decouple", OTHER, build, config={}, lineage=[], on_corrupt=on_corrupt
    )
    assert build.calls == 1 and not info.cache_hit and not info.replaced_corrupt
    assert artifact.meta["calls"] == 1 and store.verify() == []


def test_a_lock_file_gc_unlinks_under_a_waiter_is_not_taken_by_it(tmp_path, monkeypatch):
    # gc deletes a free lock file while holding it; a waiter that opened the file just before
    # then flocks an inode no longer at the path, while a newcomer locks a new one there. The
    # store relies on filelock (>= 3.20.4) seeing this and trying again, or both would build.
    store = ArtifactStore(tmp_path)
    lock_file = store.root / ".locks" / f"decouple.{KEY}.lock"
    lock_file.parent.mkdir(parents=True)
    lock_file.touch()
    real_flock = fcntl.flock
    waiting = []

    def gc_between_open_and_flock(fd, operation):
        if operation & fcntl.LOCK_EX and not waiting:
            waiting.append(fd)  # the waiter has the old file open: gc runs now
            store.gc()
            assert not lock_file.exists()
        return real_flock(fd, operation)

    monkeypatch.setattr(fcntl, "flock", gc_between_open_and_flock)
    with FileLock(str(lock_file)):
        monkeypatch.undo()
        assert lock_file.exists(), "the waiter holds a lock on a deleted file"
        with pytest.raises(Timeout):
            FileLock(str(lock_file)).acquire(timeout=0)
