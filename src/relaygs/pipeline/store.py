"""The content-addressed artifact store: build each artifact once (a file lock per key, temp
folders renamed in), load it verified (docs/artifacts.md)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

from filelock import FileLock
from safetensors import SafetensorError

import relaygs
from relaygs.errors import RERUN_COMMAND, InputError, RelayGSError
from relaygs.pipeline.artifact import Artifact, read_artifact_files, write_artifact_files
from relaygs.pipeline.context import BuildContext, building
from relaygs.pipeline.fsio import publish_dir, remove_tree
from relaygs.pipeline.gc import GcReport, collect_garbage, lock_if_free
from relaygs.pipeline.integrity import (
    CorruptArtifactError,
    check_seal,
    folder_identity,
    is_sealed,
    seal,
)
from relaygs.pipeline.keys import canonical_json
from relaygs.pipeline.layout import (
    TEMP_PREFIX,
    artifact_dir,
    checkpoint_dir,
    key_dirs,
    lock_path,
    make_temp_dir,
)
from relaygs.pipeline.manifest import (
    LineageEntry,
    Manifest,
    describe_files,
    read_manifest,
    write_manifest,
)

OnCorrupt = Literal["rebuild", "error"]
ON_CORRUPT_CHOICES = ("rebuild", "error")
VERIFY_HINT = "`python -m relaygs.artifacts verify` lists the damaged artifacts"
HEX_DIGITS = frozenset("0123456789abcdef")


def checked_key_prefix(text: str) -> str:
    """`text` as a key prefix (trimmed, lower case), or an InputError unless it is at least 4
    hex digits: the tools take this check as a usage error, before any work."""
    prefix = text.strip().lower()
    if len(prefix) < 4 or any(digit not in HEX_DIGITS for digit in prefix):
        raise InputError(
            f"key prefix {text!r}: expected at least 4 hex digits (0-9, a-f), as `ls` lists keys"
        )
    return prefix


class MissingArtifactError(RelayGSError, LookupError):
    """The requested artifact is not in the store (or is ambiguous by key prefix)."""


class ArtifactChangedError(MissingArtifactError):
    """Another process removed (gc) or replaced (a rebuild) the artifact while it was read."""


@dataclass(frozen=True)
class BuildInfo:
    """How `get_or_build` satisfied a request (a hit or a build), with the build time, size
    and provenance its manifest records, so callers need not read the store again."""

    stage: str
    key: str
    cache_hit: bool
    wall_seconds: float
    path: Path
    size_mb: float
    replaced_corrupt: str | None = None  # why the stored artifact it replaced failed its check
    provenance: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class StoredArtifact:
    """A finished artifact found in the store, with its manifest."""

    path: Path
    manifest: Manifest

    @property
    def stage(self) -> str:
        """Stage type that produced it."""
        return self.manifest.stage

    @property
    def key(self) -> str:
        """Its content-addressed key."""
        return self.manifest.key


@dataclass(frozen=True)
class VerifyProblem:
    """One artifact folder that failed verification, and why."""

    path: Path
    message: str


class ArtifactStore:
    """Artifacts under `<root>/<stage>/<key>/`; the root is made absolute at construction."""

    def __init__(self, root: Path | str) -> None:
        """A store at `root` (`~` expanded, made absolute; created when first written)."""
        self.root = Path(root).expanduser().resolve()

    def path(self, stage: str, key: str) -> Path:
        """Folder where artifact `key` of `stage` lives (whether or not it exists yet)."""
        return artifact_dir(self.root, stage, key)

    def has(self, stage: str, key: str) -> bool:
        """True when a finished (sealed) artifact exists; its bytes are not checked here."""
        return is_sealed(self.path(stage, key))

    def manifest(self, stage: str, key: str) -> Manifest:
        """The manifest of a finished artifact (not hash-checked)."""
        self._require(stage, key)
        return read_manifest(self.path(stage, key))

    def load(self, stage: str, key: str, verify: bool = True) -> Artifact:
        """Load an artifact, with `verify` its hashes checked (CorruptArtifactError); one another
        process's gc or rebuild cut short raises ArtifactChangedError."""
        return self._load_unchanged(stage, key, verify)[0]

    def get_or_build(
        self,
        stage: str,
        key: str,
        build: Callable[[], Artifact],
        *,
        config: Mapping[str, Any],
        lineage: Sequence[LineageEntry],
        provenance: Mapping[str, Any] | None = None,
        on_corrupt: OnCorrupt = "rebuild",
    ) -> tuple[Artifact, BuildInfo]:
        """Load artifact `key` of `stage`, building it once (others wait) if missing or corrupt
        (or refusing with `on_corrupt="error"`); `build` runs with `current_build()` set."""
        manifest_fields = {
            "config": json.loads(canonical_json(config, f"{stage} config")),
            "lineage": list(lineage),
            "provenance": json.loads(canonical_json(provenance or {}, f"{stage} provenance")),
        }
        hit, _ = self._try_load(stage, key, on_corrupt)
        lock_file = lock_path(self.root, stage, key)
        if hit is not None:
            self._clear_stale_checkpoints(stage, key, lock_file)
            return hit
        lock_file.parent.mkdir(parents=True, exist_ok=True)
        with FileLock(str(lock_file)):
            hit, replaced_corrupt = self._try_load(stage, key, on_corrupt)
            if hit is not None:
                remove_tree(checkpoint_dir(self.root, stage, key))
                return hit
            for leftover in (self.root / stage).glob(f"{TEMP_PREFIX}{key}-*"):
                remove_tree(leftover)  # a killed build's (this process holds the key's lock)
            context = BuildContext(self.root, stage, key)
            with building(context):
                started = time.perf_counter()
                artifact = build()
                wall_seconds = time.perf_counter() - started + context.earlier_seconds
            if not isinstance(artifact, Artifact):
                raise InputError(
                    f"stage {stage!r} returned a {type(artifact).__name__}, expected an Artifact "
                    "(a stage function ends with `return SceneModel(...).to_artifact(meta)`)"
                )
            if artifact.stage != stage:
                raise InputError(
                    f"stage {stage!r} returned an artifact labelled {artifact.stage!r}"
                )
            stored = artifact.to_cpu_contiguous()
            fields = {**manifest_fields, "wall_seconds": wall_seconds}
            manifest = self._write(stage, key, stored, fields)
            remove_tree(checkpoint_dir(self.root, stage, key))
        return stored, self._info(manifest, cache_hit=False, replaced_corrupt=replaced_corrupt)

    def list(self) -> list[StoredArtifact]:
        """Every finished artifact, sorted by stage then creation time; temp folders are
        skipped, incomplete and unreadable ones left out (`damaged` lists them)."""
        return self._scan(check_hashes=False)[0]

    def damaged(self) -> list[VerifyProblem]:
        """The folders `list` leaves out: incomplete (no completion marker) or with an
        unreadable manifest. Hashes are not checked here; `verify` does that."""
        return self._scan(check_hashes=False)[1]

    def find(self, key_prefix: str) -> StoredArtifact:
        """The one finished artifact whose key starts with `key_prefix` (any stage); a prefix
        that matches only a damaged folder says so rather than that nothing matches."""
        prefix = checked_key_prefix(key_prefix)
        found, damaged = self._scan(check_hashes=False)
        matches = [item for item in found if item.key.startswith(prefix)]
        if not matches:
            for problem in damaged:
                if problem.path.name.startswith(prefix):
                    name = f"{problem.path.parent.name}/{problem.path.name[:16]}"
                    raise CorruptArtifactError(
                        f"artifact {name} is damaged, not missing: {problem.message}"
                    )
        if len(matches) > 1:
            names = ", ".join(f"{item.stage}/{item.key[:16]}" for item in matches)
            raise MissingArtifactError(
                f"{len(matches)} artifacts with key starting {prefix!r} in {self.root} "
                f"({names}): give more digits"
            )
        if not matches:
            raise MissingArtifactError(f"no artifact with key starting {prefix!r} in {self.root}")
        return matches[0]

    def verify(self) -> list[VerifyProblem]:
        """Check every artifact folder's hashes and decode its files; return the bad ones
        (empty when all good)."""
        return self.verify_all()[1]

    def verify_all(self) -> tuple[list[StoredArtifact], list[VerifyProblem]]:
        """`verify`, with the sound artifacts too: together they count every artifact folder."""
        return self._scan(check_hashes=True)

    def _scan(self, check_hashes: bool) -> tuple[list[StoredArtifact], list[VerifyProblem]]:
        """The readable artifacts (sorted as `list` says) and every other folder's problem;
        with `check_hashes`, hashes checked and files decoded too."""
        found, problems = [], []
        for folder in key_dirs(self.root):
            outcome = _examine_steady(folder, check_hashes)
            if isinstance(outcome, StoredArtifact):
                found.append(outcome)
            elif outcome is not None:
                problems.append(outcome)
        found.sort(key=lambda item: (item.stage, item.manifest.created, item.key))
        return found, problems

    def gc(
        self,
        keep: Collection[str] | None = None,
        dry_run: bool = False,
        annotations: Collection[str] = (),
    ) -> GcReport:
        """Remove leftovers of killed builds, stale locks and incomplete folders, and with `keep`
        what is not kept (`collect_garbage`)."""
        return collect_garbage(self.root, keep, dry_run, annotations)

    def _try_load(
        self, stage: str, key: str, on_corrupt: OnCorrupt
    ) -> tuple[tuple[Artifact, BuildInfo] | None, str | None]:
        """(a verified hit, None), (None, what is wrong) when it is rebuildably corrupt, or (None,
        None) when missing or moved meanwhile (asked again under the key's lock)."""
        try:
            artifact, manifest = self._load_unchanged(stage, key, verify=True)
        except MissingArtifactError:  # ArtifactChangedError included
            return None, None
        except CorruptArtifactError as error:
            if on_corrupt == "error":
                raise CorruptArtifactError(
                    f"{error} (artifacts.on_corrupt=error: delete it or rerun with "
                    "artifacts.on_corrupt=rebuild)"
                ) from error
            return None, str(error)
        return (artifact, self._info(manifest, cache_hit=True)), None

    def _info(
        self, manifest: Manifest, cache_hit: bool, replaced_corrupt: str | None = None
    ) -> BuildInfo:
        """The BuildInfo of a stored artifact, its cost and size as its manifest records them."""
        path = self.path(manifest.stage, manifest.key)
        return BuildInfo(
            manifest.stage,
            manifest.key,
            cache_hit,
            manifest.wall_seconds,
            path,
            manifest.size_mb,
            replaced_corrupt,
            manifest.provenance,
        )

    def _load_unchanged(self, stage: str, key: str, verify: bool) -> tuple[Artifact, Manifest]:
        """The artifact (hashes checked with `verify`) and its manifest; a failure becomes
        ArtifactChangedError when the folder was removed or replaced (renamed) meanwhile."""
        folder = self.path(stage, key)
        identity = folder_identity(folder)
        if identity is None:  # no folder to compare with: one published from now on is not read
            raise MissingArtifactError(f"no artifact {stage}/{key} in {self.root}")
        try:
            self._require(stage, key)
            if verify:
                check_seal(folder)
            manifest = read_own_manifest(folder)
            return read_decodable_files(folder, stage), manifest
        except (MissingArtifactError, CorruptArtifactError) as error:
            if folder_identity(folder) == identity:
                raise
            raise ArtifactChangedError(
                f"{folder} was removed or replaced by another process while it was read "
                f"(a gc or a rebuild): {RERUN_COMMAND}"
            ) from error

    def _write(
        self, stage: str, key: str, artifact: Artifact, manifest_fields: dict[str, Any]
    ) -> Manifest:
        """Write the artifact into a temp folder, seal it, and rename it into place; return
        its manifest."""
        metrics = artifact.meta.get("metrics", {})
        if not isinstance(metrics, dict):
            raise InputError(f"{stage} artifact meta['metrics'] must be a mapping, got {metrics!r}")
        final = self.path(stage, key)
        temp = make_temp_dir(final.parent, key)
        try:
            names = write_artifact_files(temp, artifact)
            manifest = Manifest(
                key=key,
                stage=stage,
                metrics=metrics,
                created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
                package_version=relaygs.__version__,
                files=describe_files(temp, names),
                **manifest_fields,
            )
            write_manifest(temp, manifest)
            seal(temp)
            # replace anything a load would refuse
            if not isinstance(_examine(final, check_hashes=True), StoredArtifact):
                publish_dir(temp, final)
        finally:
            remove_tree(temp)
        return manifest

    def _clear_stale_checkpoints(self, stage: str, key: str, lock_file: Path) -> None:
        """Delete the checkpoints of a finished artifact that a build killed between storing it
        and deleting them left behind, unless another process holds the key's lock."""
        folder = checkpoint_dir(self.root, stage, key)
        if not folder.exists():
            return
        lock_file.parent.mkdir(parents=True, exist_ok=True)
        with lock_if_free(lock_file) as free:
            if free:
                remove_tree(folder)

    def _require(self, stage: str, key: str) -> None:
        """Raise MissingArtifactError unless a finished artifact exists."""
        if not self.has(stage, key):
            raise MissingArtifactError(f"no artifact {stage}/{key} in {self.root}")


def read_own_manifest(folder: Path) -> Manifest:
    """The manifest of artifact folder `<root>/<stage>/<key>`, once it names that stage and
    key: a folder copied or renamed under another key is corrupt there, its hashes intact."""
    manifest = read_manifest(folder)
    stage, key = folder.parent.name, folder.name
    if (manifest.stage, manifest.key) != (stage, key):
        raise CorruptArtifactError(
            f"{folder}: manifest names {manifest.stage}/{manifest.key}, not {stage}/{key}"
        )
    return manifest


def _examine(folder: Path, check_hashes: bool) -> StoredArtifact | VerifyProblem:
    """The artifact in `folder`, or its problem (an unreadable folder is one too); with
    `check_hashes`, hashes checked and files decoded (damage before sealing matches)."""
    try:
        if not is_sealed(folder):
            return VerifyProblem(folder, "incomplete (no completion marker)")
        if check_hashes:
            check_seal(folder)
        manifest = read_own_manifest(folder)
        if check_hashes:
            read_decodable_files(folder, manifest.stage)
        return StoredArtifact(folder, manifest)
    except CorruptArtifactError as error:
        return VerifyProblem(folder, str(error))
    except PermissionError as error:
        return VerifyProblem(folder, f"cannot be read ({error.strerror})")


def read_decodable_files(folder: Path, stage: str) -> Artifact:
    """The artifact files in `folder`, or CorruptArtifactError naming the folder when they do
    not decode (a file damaged before it was sealed, its hashes intact)."""
    try:
        return read_artifact_files(folder, stage)
    except (OSError, ValueError, SafetensorError) as error:
        raise CorruptArtifactError(f"{folder}: unreadable artifact files ({error})") from error


def _examine_steady(folder: Path, check_hashes: bool) -> StoredArtifact | VerifyProblem | None:
    """`_examine` of a folder no other process moved meanwhile: a problem seen while gc removed
    the folder (None: it is gone) or a rebuild replaced it (looked at again) is not its own."""
    identity = folder_identity(folder)
    while identity is not None:
        outcome = _examine(folder, check_hashes)
        now = folder_identity(folder)
        if isinstance(outcome, StoredArtifact) or now == identity:
            return outcome
        identity = now
    return None
