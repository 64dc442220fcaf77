#!/usr/bin/env bash
# Create .venv with relaygs installed (editable, with dev extras).
# Respects a torch the user already has: if $PYTHON can import torch, the venv sees it
# (system site packages, plus a .pth to its site folder when $PYTHON is itself a venv's,
# whose packages a venv made from it would not see); otherwise torch is installed first
# (TORCH_SPEC, default torch==2.13.0: the CPU build where pip's wheel source offers it).
set -euo pipefail
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
stamp="$VENV/.relaygs-installed"

# Make the torch that $PYTHON imports importable in $VENV, wherever it is installed.
share_torch_site() {
  if "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
    return
  fi
  local site
  site=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
  "$PYTHON" -c 'import os, torch; print("import site; site.addsitedir(%a)"
    % os.path.dirname(os.path.dirname(torch.__file__)))' >"$site/relaygs-torch-site.pth"
}

if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ]; then
  exit 0
fi
if [ ! -x "$VENV/bin/python" ]; then
  if "$PYTHON" -c "import torch" >/dev/null 2>&1; then
    echo "setup: using the torch already installed for $PYTHON"
    "$PYTHON" -m venv --system-site-packages "$VENV"
    share_torch_site
  else
    "$PYTHON" -m venv "$VENV"
  fi
fi
if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  echo "setup: no torch found; installing the CPU build ($TORCH_SPEC)"
  "$VENV/bin/python" -m pip install -qq "$TORCH_SPEC"
fi
"$VENV/bin/python" -m pip install -qq -e ".[dev]"
touch "$stamp"
