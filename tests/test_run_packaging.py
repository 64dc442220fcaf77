"""conf/ (the pipelines included) and the native kernels' C++ source ship inside the package:
the `_data` link and pyproject's package-data globs cover every file, so a regular install
finds the same configs as the repository and can build the kernels."""

from pathlib import Path

from relaygs import paths


def _install(monkeypatch, package_dir):
    """Point `relaygs.paths` at a copy of the package in `package_dir` (data files only)."""
    (package_dir / "_data" / "conf").mkdir(parents=True)
    (package_dir / "_data" / "conf" / "config.yaml").write_text("packaged: true\n")
    monkeypatch.setattr(paths, "PACKAGE_DIR", package_dir)
    monkeypatch.setattr(paths, "REPO_ROOT", package_dir.parents[1])
    monkeypatch.setattr(paths, "PACKAGED_DATA_DIR", package_dir / "_data")


def _foreign_conf(app):
    """Another project's Hydra config tree at `app/conf`."""
    (app / "conf").mkdir()
    (app / "conf" / "config.yaml").write_text("other_app: 1\n")


def test_an_installed_copy_ignores_a_conf_folder_beside_its_install_dir(monkeypatch, tmp_path):
    _install(monkeypatch, tmp_path / "app" / "lib" / "relaygs")  # pip install --target app/lib
    _foreign_conf(tmp_path / "app")
    assert paths.config_dir() == tmp_path / "app" / "lib" / "relaygs" / "_data" / "conf"
    (tmp_path / "app" / "pyproject.toml").write_text('[project]\nname = "relaygs"\n')
    assert paths.config_dir() == tmp_path / "app" / "lib" / "relaygs" / "_data" / "conf"


def test_a_checkout_uses_its_own_conf_folder(monkeypatch, tmp_path):
    _install(monkeypatch, tmp_path / "repo" / "src" / "relaygs")
    _foreign_conf(tmp_path / "repo")
    assert paths.config_dir() == paths.PACKAGED_DATA_DIR / "conf"  # no relaygs pyproject.toml
    (tmp_path / "repo" / "pyproject.toml").write_text('[project]\nname = "otherapp"\n')
    assert paths.config_dir() == paths.PACKAGED_DATA_DIR / "conf"  # another project's
    (tmp_path / "repo" / "pyproject.toml").write_text('[project]\nname = "relaygs"\n')
    assert paths.config_dir() == tmp_path / "repo" / "conf"


def test_an_editable_install_uses_the_repository_conf_its_packaged_link_points_at():
    assert paths.config_dir() == paths.REPO_ROOT / "conf"
    assert (paths.config_dir() / "config.yaml").is_file()
    assert (paths.PACKAGED_DATA_DIR / "conf").resolve() == paths.REPO_ROOT / "conf"


def test_package_data_globs_cover_every_config_pipeline_and_kernel_source_file(pyproject):
    patterns = pyproject["tool"]["setuptools"]["package-data"]["relaygs"]
    shipped = {
        path.relative_to(paths.PACKAGE_DIR).as_posix()
        for pattern in patterns
        for path in paths.PACKAGE_DIR.glob(pattern)
    }
    expected = {
        f"_data/{path.relative_to(paths.REPO_ROOT).as_posix()}"
        for path in Path(paths.REPO_ROOT, "conf").rglob("*")
        if path.is_file()
    }
    native = paths.PACKAGE_DIR / "splat" / "native"
    kernels = {
        path.relative_to(paths.PACKAGE_DIR).as_posix()
        for path in native.iterdir()
        if path.suffix in (".cpp", ".h")
    }
    assert expected and kernels and shipped == expected | kernels
