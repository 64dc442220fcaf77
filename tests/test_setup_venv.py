"""tools/setup_venv.sh reuses the torch its python imports (a venv made from a venv's python sees
its torch); with none, it installs a CPU build only, unless told to take a CUDA one."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch

from relaygs import paths

SCRIPT = paths.REPO_ROOT / "tools" / "setup_venv.sh"
SETUP_VARIABLES = ("PIP_", "PYTHON", "TORCH_", "ALLOW_CUDA_TORCH", "VENV")
needs_bash = pytest.mark.skipif(
    not SCRIPT.is_file() or shutil.which("bash") is None, reason="needs bash"
)


def _setup_free_environment() -> dict[str, str]:
    """This process's environment less what steers pip or the setup script (a make run with
    ALLOW_CUDA_TORCH=1 must not leak it into a test that expects a refusal)."""
    return {k: v for k, v in os.environ.items() if not k.startswith(SETUP_VARIABLES)}


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="needs tests run from a venv's python")
@needs_bash
def test_a_venv_made_from_a_venvs_python_reuses_its_torch(tmp_path):
    venv = tmp_path / "venv"
    env = _setup_free_environment()
    # pip offline with no wheel source: any install fails at once instead of downloading
    env |= {"VENV": str(venv), "PYTHON": sys.executable, "PIP_CONFIG_FILE": os.devnull}
    env |= {"PIP_NO_INDEX": "1", "TORCH_SPEC": "torch==0.0.0"}
    done = subprocess.run(
        ["bash", str(SCRIPT)], cwd=paths.REPO_ROOT, env=env, capture_output=True, text=True
    )
    assert "using the torch already installed" in done.stdout, done.stdout + done.stderr
    assert "no torch found" not in done.stdout, done.stdout + done.stderr
    probe = [str(venv / "bin" / "python"), "-c", "import torch; print(torch.__file__)"]
    found = subprocess.run(probe, env=env, capture_output=True, text=True, check=True).stdout
    assert found.strip() == torch.__file__


def _fake_wheel(folder: Path, name: str, requires: list[str], version: str) -> None:
    """Write a wheel NAME 0.0.1 that depends on REQUIRES and holds a module NAME whose
    __version__ is VERSION, for pip to resolve and install offline."""
    dist_info = f"{name}-0.0.1.dist-info"
    metadata = f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.0.1\n"
    metadata += "".join(f"Requires-Dist: {req}\n" for req in requires)
    wheel = "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"
    with zipfile.ZipFile(folder / f"{name}-0.0.1-py3-none-any.whl", "w") as archive:
        archive.writestr(f"{name}/__init__.py", f"__version__ = {version!r}\n")
        archive.writestr(f"{dist_info}/METADATA", metadata)
        archive.writestr(f"{dist_info}/WHEEL", wheel)
        archive.writestr(f"{dist_info}/RECORD", "")


def _python_without_torch(folder: Path) -> str:
    """A python command that cannot import torch: this interpreter without site-packages."""
    wrapper = folder / "python-without-site"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -S "$@"\n')
    wrapper.chmod(0o755)
    return str(wrapper)


def _setup_with_fake_torch(
    tmp_path: Path, torch_requires: list[str], torch_version: str, allow_cuda: bool
) -> tuple[subprocess.CompletedProcess, Path]:
    """Run the setup script traced (bash -x), offline, on a python without torch, pip finding
    only fake torch/nvidia wheels: the project's own install then fails, non-zero, unstamped."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    _fake_wheel(wheels, "torch", torch_requires, torch_version)
    _fake_wheel(wheels, "nvidia_fake_runtime", [], "0.0.1")
    venv = tmp_path / "venv"
    env = _setup_free_environment()
    env |= {"VENV": str(venv), "PYTHON": _python_without_torch(tmp_path)}
    env |= {"PIP_CONFIG_FILE": os.devnull, "PIP_NO_INDEX": "1", "PIP_FIND_LINKS": str(wheels)}
    env |= {"TORCH_SPEC": "torch==0.0.1"} | ({"ALLOW_CUDA_TORCH": "1"} if allow_cuda else {})
    done = subprocess.run(
        ["bash", "-x", str(SCRIPT)], cwd=paths.REPO_ROOT, env=env, capture_output=True, text=True
    )
    assert done.returncode != 0
    assert not (venv / ".relaygs-installed").exists()
    return done, venv


def _reached_the_project_install(trace: str, pins: str = "") -> bool:
    """Whether the traced run got as far as `pip install -e .[dev]` (with these extra args)."""
    return any(line.endswith(f"-e '.[dev]'{pins}") for line in trace.splitlines())


@pytest.mark.parametrize(
    ("torch_requires", "allow_cuda", "refused"),
    [
        (["nvidia-fake-runtime"], False, True),
        (["nvidia-fake-runtime"], True, False),
        ([], False, False),
    ],
    ids=["cuda-build-refused", "cuda-build-allowed", "cpu-build-installed"],
)
@needs_bash
def test_setup_stops_before_pip_installs_a_cuda_build_of_torch(
    tmp_path, torch_requires, allow_cuda, refused
):
    # torch 2.3, the first built against numpy 2: the project installs without a numpy pin
    done, venv = _setup_with_fake_torch(tmp_path, torch_requires, "2.3.0", allow_cuda)
    said = done.stdout + done.stderr
    assert ("setup: pip would install a CUDA build of torch==0.0.1" in done.stderr) == refused
    # refused: the venv this run made is gone (a torch installed for PYTHON later must show
    # through a new one); otherwise the fake torch is in and the run went on to the project
    assert venv.exists() != refused, said
    assert _reached_the_project_install(done.stderr) != refused, said
    assert "keeping numpy<2" not in said


@needs_bash
def test_setup_keeps_numpy_1_under_a_torch_older_than_2_3(tmp_path):
    done, _ = _setup_with_fake_torch(tmp_path, [], "2.1.2+cu121", allow_cuda=False)
    said = done.stdout + done.stderr
    assert "predates numpy 2; keeping numpy<2" in done.stdout, said
    assert _reached_the_project_install(done.stderr, " 'numpy<2'"), said
