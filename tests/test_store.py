"""ArtifactStore in one process: layout, manifest, cache hits, corruption, missing keys, gc."""

import json
import shutil

import pytest
import torch
from filelock import FileLock

import relaygs
from refusals import refused
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.context import current_build
from relaygs.pipeline.integrity import MARKER_FILE, CorruptArtifactError
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.manifest import LineageEntry
from relaygs.pipeline.store import ArtifactStore, MissingArtifactError
from store_helpers import KEY, OTHER, CountingBuild, damage_dtype_and_rehash, flip_last_byte, sealed

CHILD_KEY = artifact_key("relay", 1, {"k": 4}, "scene", [KEY])


def _build(store, fake, key=KEY, **kwargs):
    kwargs.setdefault("config", {"steps": 3})
    kwargs.setdefault("lineage", [])
    return store.get_or_build(fake.stage, key, fake, **kwargs)


def test_layout_manifest_and_marker_are_written_and_a_hit_does_not_rebuild(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    store, fake = ArtifactStore("store"), CountingBuild()
    assert store.root.is_absolute() and store.root == (tmp_path / "store").resolve()
    built, first = _build(store, fake, provenance={"node": "decouple"})
    folder = store.root / "decouple" / KEY
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [MARKER_FILE, "manifest.json", "meta.json", "tensors.safetensors"]
    )
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["key"] == KEY and manifest["stage"] == "decouple"
    assert manifest["config"] == {"steps": 3} and manifest["lineage"] == []
    assert manifest["metrics"] == {"loss": 0.5} and manifest["wall_seconds"] >= 0
    assert manifest["package_version"] == relaygs.__version__
    assert manifest["created"].endswith("+00:00")
    assert manifest["provenance"] == {"node": "decouple"}
    assert set(manifest["files"]) == {"meta.json", "tensors.safetensors"}
    on_disk = sum((folder / name).stat().st_size for name in manifest["files"])
    assert store.manifest("decouple", KEY).size_mb == pytest.approx(on_disk / 1e6)
    assert not list((store.root / "decouple").glob(".tmp-*"))
    loaded, second = _build(store, fake)
    assert fake.calls == 1
    assert not first.cache_hit and second.cache_hit
    assert second.wall_seconds == first.wall_seconds
    # the size a job reports comes from here, not from a second read of a store gc may change
    assert second.size_mb == first.size_mb == store.manifest("decouple", KEY).size_mb > 0
    assert torch.equal(loaded.tensors["xyz"], built.tensors["xyz"])
    assert loaded.meta == built.meta


@pytest.mark.parametrize(
    ("damage", "named"),
    [
        (lambda f: flip_last_byte(f / "tensors.safetensors"), ["tensors.safetensors"]),
        (lambda f: flip_last_byte(f / "meta.json"), ["meta.json"]),
        (lambda f: flip_last_byte(f / "manifest.json"), ["manifest.json"]),
        (lambda f: (f / MARKER_FILE).write_text("{not json"), [MARKER_FILE]),
        (lambda f: (f / MARKER_FILE).write_text('{"sha256": ["x"]}'), ["marker"]),
        (lambda f: (f / "tensors.safetensors").unlink(), ["tensors.safetensors", "missing"]),
        (lambda f: (f / "meta.json").unlink(), ["meta.json", "missing"]),
        # hashes that match undecodable bytes: safetensors' own error escaped as a traceback
        (sealed("meta.json", "{not json"), ["unreadable"]),
        (sealed("tensors.safetensors", "{not json"), ["unreadable"]),
        (damage_dtype_and_rehash, ["unreadable artifact files"]),
    ],
)
def test_a_damaged_artifact_is_named_refused_under_error_and_rebuilt(tmp_path, damage, named):
    store, fake = ArtifactStore(tmp_path), CountingBuild()
    _build(store, fake)
    damage(store.path("decouple", KEY))
    assert [problem.path.name for problem in store.verify()] == [KEY]
    with refused(CorruptArtifactError, *named):
        store.load("decouple", KEY)
    with refused(CorruptArtifactError, *named, "on_corrupt=rebuild"):
        _build(store, fake, on_corrupt="error")
    assert fake.calls == 1
    artifact, info = _build(store, fake)
    assert fake.calls == 2 and not info.cache_hit and info.replaced_corrupt
    assert store.load("decouple", KEY).meta["calls"] == artifact.meta["calls"] == 2
    assert store.verify() == []


def test_missing_and_malformed_requests_fail_clearly(tmp_path):
    store = ArtifactStore(tmp_path)
    with refused(MissingArtifactError, f"decouple/{KEY}"):
        store.load("decouple", KEY)
    with refused(InputError, "'../etc'"):
        store.has("decouple", "../etc")
    with refused(InputError, "'../x'"):
        store.has("../x", KEY)
    fake = CountingBuild()
    with refused(InputError, "decouple", "seeds", "set"):
        _build(store, fake, config={"seeds": {1, 2}})
    assert fake.calls == 0
    with refused(InputError, "'relay'", "'decouple'"):
        store.get_or_build("decouple", KEY, CountingBuild("relay"), config={}, lineage=[])
    assert not store.has("decouple", KEY)
    with refused(InputError, "'decouple'", "dict"):
        store.get_or_build("decouple", KEY, lambda: {"x": 1}, config={}, lineage=[])
    assert not store.has("decouple", KEY)


def test_build_sees_its_context_and_checkpoints_are_removed_on_completion(tmp_path):
    store = ArtifactStore(tmp_path)
    seen = []

    def build():
        context = current_build()
        seen.append((context.stage, context.key, context.store_root))
        context.checkpointer(1).save(1, {"x": torch.ones(2)})
        assert (store.root / "decouple" / f"{KEY}.ckpt").is_dir()
        context.earlier_seconds = 1000.0  # as the training loop sets on resuming
        return Artifact("decouple", {}, {})

    _, info = store.get_or_build("decouple", KEY, build, config={}, lineage=[])
    assert seen == [("decouple", KEY, store.root)]
    assert current_build() is None
    assert not (store.root / "decouple" / f"{KEY}.ckpt").exists()
    # a resumed build costs the seconds before its checkpoint too
    assert 1000.0 <= info.wall_seconds < 1060.0
    assert store.manifest("decouple", KEY).wall_seconds == info.wall_seconds


def _raising():
    raise RuntimeError("boom")


@pytest.mark.parametrize(
    ("build", "error", "named"),
    [
        (_raising, RuntimeError, ["boom"]),
        (
            lambda: Artifact("decouple", {"xyz": torch.zeros(2, 3)}, {"metrics": [0.5]}),
            InputError,
            ["decouple", "meta['metrics']"],
        ),
    ],
)
def test_a_failing_build_or_one_whose_metrics_are_no_mapping_stores_nothing(
    tmp_path, build, error, named
):
    store = ArtifactStore(tmp_path)
    with refused(error, *named):
        store.get_or_build("decouple", KEY, build, config={}, lineage=[])
    assert not store.has("decouple", KEY) and store.list() == [] and store.damaged() == []


def test_leftover_temp_dirs_are_ignored_by_list_and_removed_by_gc_or_the_next_build(tmp_path):
    store = ArtifactStore(tmp_path)
    stage_dir = store.root / "decouple"
    killed = stage_dir / f".tmp-{KEY}-killed"  # a killed build's, cleared by the next
    killed.mkdir(parents=True)
    (killed / "meta.json").write_text("{")
    _build(store, CountingBuild())
    assert not killed.exists() and store.verify() == []
    leftover = stage_dir / f".tmp-{CHILD_KEY}-abc123"
    leftover.mkdir()
    (leftover / "tensors.safetensors").write_bytes(b"half")
    incomplete = stage_dir / CHILD_KEY
    incomplete.mkdir()
    stale_ckpt = stage_dir / f"{KEY}.ckpt"
    stale_ckpt.mkdir()
    assert [item.key for item in store.list()] == [KEY]
    assert not store.has("decouple", CHILD_KEY)
    locks = sorted((store.root / ".locks").iterdir())
    dry = store.gc(dry_run=True)
    assert set(dry.removed) >= {leftover, incomplete, stale_ckpt, *locks}
    assert leftover.exists() and locks and all(lock.exists() for lock in locks)
    report = store.gc()
    assert not leftover.exists() and not incomplete.exists() and not stale_ckpt.exists()
    assert not list((store.root / ".locks").iterdir())
    assert store.has("decouple", KEY) and set(report.removed) >= {leftover, incomplete}


def test_gc_skips_entries_whose_lock_is_held(tmp_path):
    store = ArtifactStore(tmp_path)
    leftover = store.root / "decouple" / f".tmp-{KEY}-busy"
    leftover.mkdir(parents=True)
    lock_file = store.root / ".locks" / f"decouple.{KEY}.lock"
    lock_file.parent.mkdir()
    with FileLock(str(lock_file)):
        report = store.gc()
    assert leftover.exists() and leftover in report.busy and lock_file in report.busy


def test_lineage_is_recorded_and_gc_with_a_keep_set_keeps_it_and_removes_the_rest(tmp_path):
    store = ArtifactStore(tmp_path)
    _build(store, CountingBuild())
    lineage = [LineageEntry("decouple", "decouple", KEY)]
    _build(store, CountingBuild("relay"), key=CHILD_KEY, config={"k": 4}, lineage=lineage)
    assert store.manifest("relay", CHILD_KEY).lineage == lineage
    _build(store, CountingBuild(offset=1), key=OTHER)
    leftover = store.root / "decouple" / f".tmp-{KEY}-killed"
    leftover.mkdir()
    unknown = "0" * 64
    with refused(InputError, unknown):  # keeping an unknown key removes nothing
        store.gc(keep={KEY, unknown})
    assert store.has("decouple", OTHER) and leftover.exists()
    store.gc(keep={CHILD_KEY})
    assert store.has("relay", CHILD_KEY) and store.has("decouple", KEY)
    assert not store.has("decouple", OTHER) and not leftover.exists()


def test_a_folder_copied_under_another_key_is_not_loaded_as_that_key(tmp_path):
    # The copy's files match their own hashes, but its manifest names KEY, not OTHER.
    store, fake = ArtifactStore(tmp_path), CountingBuild()
    _build(store, fake)
    shutil.copytree(store.path("decouple", KEY), store.path("decouple", OTHER))
    assert store.has("decouple", OTHER)
    with refused(CorruptArtifactError, f"decouple/{KEY}", OTHER):
        store.load("decouple", OTHER)
    assert [problem.path.name for problem in store.verify()] == [OTHER]
    assert [item.key for item in store.list()] == [KEY]
    with refused(CorruptArtifactError, f"decouple/{KEY}", "on_corrupt"):
        _build(store, fake, key=OTHER, on_corrupt="error")
    assert fake.calls == 1
    rebuild = CountingBuild(offset=1)
    artifact, info = _build(store, rebuild, key=OTHER)
    assert not info.cache_hit and info.replaced_corrupt
    assert artifact.tensors["xyz"][0, 0] == 1.0
    # the rebuild replaced the copy: the key is served from the store from now on
    assert store.manifest("decouple", OTHER).key == OTHER and store.verify() == []
    _, again = _build(store, rebuild, key=OTHER)
    assert again.cache_hit and rebuild.calls == 1


def test_gc_keeps_only_annotations_whose_upstreams_are_all_kept(tmp_path):
    store = ArtifactStore(tmp_path)
    _build(store, CountingBuild())
    _build(store, CountingBuild(offset=1), key=OTHER)
    evaluate = CountingBuild("evaluate")
    described = artifact_key("evaluate", 1, {}, "scene", [KEY])
    of_other = artifact_key("evaluate", 1, {}, "scene", [OTHER])
    orphan = artifact_key("evaluate", 1, {}, "scene", [])
    _build(store, evaluate, key=described, lineage=[LineageEntry("decouple", "decouple", KEY)])
    _build(store, evaluate, key=of_other, lineage=[LineageEntry("decouple", "decouple", OTHER)])
    _build(store, evaluate, key=orphan)  # describes nothing: nothing keeps it
    store.gc(keep={KEY}, annotations={"evaluate"})
    assert store.has("decouple", KEY) and store.has("evaluate", described)
    assert not store.has("decouple", OTHER) and not store.has("evaluate", of_other)
    assert not store.has("evaluate", orphan)


@pytest.mark.parametrize("prefix", [KEY[:3], "zzzz", KEY[:3] + "-"])
def test_a_key_prefix_under_4_hex_digits_is_refused(tmp_path, prefix):
    store = ArtifactStore(tmp_path)
    _build(store, CountingBuild())
    assert store.find(KEY[:4].upper()).key == KEY
    with refused(InputError, f"'{prefix}'", "hex digits"):
        store.find(prefix)
