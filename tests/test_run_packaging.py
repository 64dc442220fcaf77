"""conf/ and pipelines/ ship inside the package: the `_data` links and pyproject's package-data
globs cover every file, so a regular install finds the same configs as the repository."""

from pathlib import Path

import pytest

from relaygs import paths

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11


def test_packaged_data_links_point_at_the_repository_folders():
    assert (paths.PACKAGED_DATA_DIR / "conf").resolve() == paths.REPO_ROOT / "conf"
    assert (paths.PACKAGED_DATA_DIR / "pipelines").resolve() == paths.REPO_ROOT / "pipelines"


def test_package_data_globs_cover_every_config_and_pipeline_file():
    pyproject = tomllib.loads((paths.REPO_ROOT / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["relaygs"]
    shipped = {
        path.relative_to(paths.PACKAGE_DIR).as_posix()
        for pattern in patterns
        for path in paths.PACKAGE_DIR.glob(pattern)
    }
    expected = {
        f"_data/{path.relative_to(paths.REPO_ROOT).as_posix()}"
        for folder in ("conf", "pipelines")
        for path in Path(paths.REPO_ROOT, folder).rglob("*")
        if path.is_file()
    }
    assert expected and shipped == expected
