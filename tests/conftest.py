"""Shared fixtures. Scene fixtures (prefix `tiny_synth`) generate miniature synthetic scenes."""

from __future__ import annotations

import contextlib
import copy
import functools
import io
import os
import shutil
import signal
import sys
from pathlib import Path
from typing import Any

import pytest
import torch

from fake_stages import FakeStages
from relaygs import paths
from relaygs.data import Scene, load_scene
from relaygs.data.synthetic import generate
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.keys import artifact_key
from relaygs.pipeline.store import ArtifactStore
from relaygs.splat import native, rasterize

TINY_SYNTH_SIZE = {"frames": 6, "width": 32, "height": 18}


@pytest.fixture(autouse=True)
def sigint_handler_restored():
    """A tool started in-process ignores Ctrl-C once its work is done; the next test (and
    the child processes it starts, which inherit an ignored SIGINT) must not."""
    handler = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, handler)


@pytest.fixture(params=["torch", "native"])
def splat_backend(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Runs a test once per splatting backend: `backend="auto"` (the default) resolves to
    this one on CPU tensors, so tests written for the default cover both."""
    chosen = request.param
    if chosen == "native":
        try:
            native.load()
        except native.NativeUnavailableError as err:
            # only a machine without a compiler may skip; a failed build fails the test
            if native.build.compiler() is not None:
                raise
            pytest.skip(f"native kernel unavailable: {err}")
    original = rasterize.select_backend

    def forced(backend: str, like: Any) -> rasterize.Backend:
        if backend == "auto" and native.supports(like):
            backend = chosen
        return original(backend, like)

    monkeypatch.setattr(rasterize, "select_backend", forced)
    monkeypatch.setattr(rasterize, "_default_backend", "auto")
    return chosen


@pytest.fixture(scope="session")
def tiny_synth_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 32×18, 6-frame `juggle` scene with its default effects (generate once, read only)."""
    return generate("juggle", tmp_path_factory.mktemp("synth") / "juggle", **TINY_SYNTH_SIZE)


@pytest.fixture
def tiny_synth_copy(tiny_synth_scene: Path, tmp_path: Path) -> Path:
    """A private copy of `tiny_synth_scene` that a test may damage."""
    return Path(shutil.copytree(tiny_synth_scene, tmp_path / "scene"))


@pytest.fixture(scope="session")
def pyproject() -> dict[str, Any]:
    """The repository's pyproject.toml, parsed: with tomllib from Python 3.11, with the dev
    extra's tomli before (skips where neither is there)."""
    toml = pytest.importorskip("tomllib" if sys.version_info >= (3, 11) else "tomli")
    return toml.loads((paths.REPO_ROOT / "pyproject.toml").read_text())


def pytest_configure(config: pytest.Config) -> None:
    """Register the suite's markers (`sweep`: the end-to-end experiment runs, minutes long) and,
    in a pytest-xdist worker, share the cores: each worker (and each process its tests start)
    takes its part of them, since two workers of two threads on two cores wait on each other."""
    config.addinivalue_line(
        "markers", "sweep: end-to-end experiment sweeps at budget=smoke (deselect: -m 'not sweep')"
    )
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        threads = max(1, (cores or 1) // workers)
        torch.set_num_threads(threads)
        os.environ["OMP_NUM_THREADS"] = str(threads)


# --- Stage fixtures (prefix `stage_`): a 48×27, 8-frame juggle scene and the artifacts of a
# short decouple → relay → deform run on it, built once per session.

STAGE_SCENE_SIZE = {"frames": 8, "width": 48, "height": 27}
STAGE_MAX_POINTS = 2000
STAGE_K = 4  # 8 frames → S = 2 relay segments
STAGE_DECOUPLE_STEPS = 200


def stage_smoke_cfg(**sections: dict) -> dict:
    """The `smoke` budget as a stage cfg (seed 0, no progress bar, k = STAGE_K), with
    `sections` merged over it key by key."""
    from relaygs.stages import step_budgets

    cfg = copy.deepcopy(step_budgets()["smoke"])
    cfg["seed"] = 0
    cfg["train"] = {**cfg.get("train", {}), "progress": False}
    cfg["relay"] = {**cfg["relay"], "k": STAGE_K}
    cfg["replicate"] = {"k": STAGE_K}
    for name, values in sections.items():
        cfg[name] = {**cfg.get(name, {}), **values}
    return cfg


@contextlib.contextmanager
def one_thread():
    """Torch on one thread inside: the stage fixtures' tiny steps gain nothing from a second
    one on an idle machine and crawl when another process holds a core (each parallel op waits
    for a time slice: 13x slower on a shared 2-core machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def stage_scene_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The stage tests' scene folder (generated once, read only)."""
    return generate("juggle", tmp_path_factory.mktemp("stages") / "juggle", **STAGE_SCENE_SIZE)


@pytest.fixture(scope="session")
def stage_scene(stage_scene_path: Path) -> Scene:
    """The stage tests' scene, its point cloud voxel-thinned to about STAGE_MAX_POINTS."""
    return load_scene(stage_scene_path, max_points=STAGE_MAX_POINTS)


@pytest.fixture(scope="session")
def stage_decoupled(stage_scene: Scene) -> Artifact:
    """Decouple long enough to separate the movers, without density control (so each final
    Gaussian is still its initial point, moved a little)."""
    from relaygs.stages import SPECS

    no_density = {"densify_until": 0, "opacity_reset_every": 0}
    cfg = stage_smoke_cfg(decouple={"steps": STAGE_DECOUPLE_STEPS, "densify": no_density})
    with one_thread():
        return SPECS["decouple"].run(stage_scene, {}, cfg)


@pytest.fixture(scope="session")
def stage_relayed(stage_scene: Scene, stage_decoupled: Artifact) -> Artifact:
    """Relay at the smoke budget (S = 2 copies), background frozen."""
    from relaygs.stages import SPECS

    with one_thread():
        return SPECS["relay"].run(stage_scene, {"decouple": stage_decoupled}, stage_smoke_cfg())


@pytest.fixture(scope="session")
def stage_deformed(stage_scene: Scene, stage_relayed: Artifact) -> Artifact:
    """Deform at the smoke budget on the relay output."""
    from relaygs.stages import SPECS

    with one_thread():
        return SPECS["deform"].run(stage_scene, {"relay": stage_relayed}, stage_smoke_cfg())


@pytest.fixture
def stored_deform(stage_deformed: Artifact, tmp_path: Path) -> tuple[ArtifactStore, str]:
    """The stage fixtures' deform artifact in a fresh store: (store, key)."""
    store = ArtifactStore(tmp_path / "store")
    key = artifact_key("deform", 1, {"steps": 20}, "juggle", [])
    store.get_or_build("deform", key, lambda: stage_deformed, config={}, lineage=[])
    return store, key


@pytest.fixture
def fakes(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> FakeStages:
    """Fake stages behind `relaygs.run` (`run_main`), launched from an empty temp folder."""
    from relaygs.app.task import run_task
    from relaygs.commands import run as run_module

    fakes = FakeStages()
    monkeypatch.setattr(run_module, "load_stage_suite", fakes.suite)
    monkeypatch.setattr(run_module, "run_task", functools.partial(run_task, suite=fakes.suite()))
    monkeypatch.chdir(tmp_path)
    return fakes


def run_main(args: list[str]) -> int | str | None:
    """Run `python -m relaygs.run` in-process; its exit status (stderr is checked by callers)."""
    from relaygs.commands import run as run_module

    try:
        return run_module.main(args)
    except SystemExit as stop:
        return stop.code


class WriteRecorder(io.StringIO):
    """A stream that records each write it is given, as an unbuffered stdout passes each one
    to the pipe (PYTHONUNBUFFERED): what jobs printing side by side could interleave."""

    def __init__(self) -> None:
        super().__init__()
        self.writes: list[str] = []

    def write(self, text: str) -> int:
        self.writes.append(text)
        return super().write(text)
