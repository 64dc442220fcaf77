"""tools/setup_venv.sh reuses the torch its python imports: a venv made from a venv's python
(`make venv` in an activated venv) sees that venv's torch instead of installing another."""

import os
import shutil
import subprocess
import sys

import pytest
import torch

from relaygs import paths

SCRIPT = paths.REPO_ROOT / "tools" / "setup_venv.sh"


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="needs tests run from a venv's python")
@pytest.mark.skipif(not SCRIPT.is_file() or shutil.which("bash") is None, reason="needs bash")
def test_a_venv_made_from_a_venvs_python_reuses_its_torch(tmp_path):
    venv = tmp_path / "venv"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PIP_", "PYTHON"))}
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
