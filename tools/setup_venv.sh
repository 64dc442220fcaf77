#!/usr/bin/env bash
# Create .venv with relaygs installed (editable, with dev extras).
# Respects a torch the user already has: if the base python can import torch,
# the venv sees it (system site packages); otherwise the CPU build is installed
# first (TORCH_SPEC, default torch==2.13.0) so pip never pulls a CUDA build.
set -euo pipefail
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
stamp="$VENV/.relaygs-installed"

if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ]; then
  exit 0
fi
if [ ! -x "$VENV/bin/python" ]; then
  if "$PYTHON" -c "import torch" >/dev/null 2>&1; then
    echo "setup: using the torch already installed for $PYTHON"
    "$PYTHON" -m venv --system-site-packages "$VENV"
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
