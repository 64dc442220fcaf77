"""Shared fixtures. Scene fixtures (prefix `tiny_synth`) generate miniature synthetic scenes."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from relaygs.data.synthetic import generate

TINY_SYNTH_SIZE = {"frames": 6, "width": 32, "height": 18}


@pytest.fixture(scope="session")
def tiny_synth_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 32×18, 6-frame `juggle` scene with its default effects (generate once, read only)."""
    return generate("juggle", tmp_path_factory.mktemp("synth") / "juggle", **TINY_SYNTH_SIZE)


@pytest.fixture
def tiny_synth_copy(tiny_synth_scene: Path, tmp_path: Path) -> Path:
    """A private copy of `tiny_synth_scene` that a test may damage."""
    return Path(shutil.copytree(tiny_synth_scene, tmp_path / "scene"))


def pytest_configure(config: pytest.Config) -> None:
    """Register the suite's markers (`sweep`: the end-to-end experiment runs, minutes long)."""
    config.addinivalue_line(
        "markers", "sweep: end-to-end experiment sweeps at budget=smoke (deselect: -m 'not sweep')"
    )
