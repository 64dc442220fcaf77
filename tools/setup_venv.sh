#!/usr/bin/env bash
# Create .venv with relaygs installed (editable, with dev extras).
# Respects a torch the user already has: if $PYTHON can import torch, the venv sees it
# (system site packages, plus a .pth to its site folder when $PYTHON is itself a venv's,
# whose packages a venv made from it would not see); otherwise torch is installed first
# (TORCH_SPEC, default torch==2.13.0: the CPU build where pip's wheel source offers it).
# Where pip would install a CUDA build instead (torch plus nvidia-* wheels, several GB),
# setup stops and says how to get the CPU build, unless ALLOW_CUDA_TORCH=1.
set -euo pipefail
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
stamp="$VENV/.relaygs-installed"
created_venv=0

# Print one line to stderr and exit 1, removing the venv if this run made it (a venv made
# without system site packages would otherwise hide a torch installed for $PYTHON later).
stop() {
  echo "setup: $*" >&2
  if [ "$created_venv" = 1 ]; then
    rm -rf "$VENV"
  fi
  exit 1
}

# Stop if installing $TORCH_SPEC would pull a CUDA build (nvidia-* wheels). pip resolves
# before installing; pip < 25.3 also downloads what it resolved, and pip < 22.2 cannot.
refuse_cuda_torch() {
  if [ "${ALLOW_CUDA_TORCH:-0}" = 1 ]; then
    return
  fi
  "$VENV/bin/python" -m pip install -qq "pip>=25.3" >/dev/null 2>&1 || true
  local usage report nvidia
  usage=$("$VENV/bin/python" -m pip install --help)
  if [[ "$usage" != *--dry-run* ]]; then
    stop "pip in $VENV is older than 22.2 and cannot tell which build of $TORCH_SPEC it" \
      "would install; upgrade it, or set ALLOW_CUDA_TORCH=1 to install what it resolves"
  fi
  report=$("$VENV/bin/python" -m pip install -qq --dry-run --ignore-installed --report - \
    "$TORCH_SPEC") || stop "pip could not resolve $TORCH_SPEC (its error is above)"
  nvidia=$("$VENV/bin/python" -c 'import json, sys
names = [p["metadata"]["name"].lower() for p in json.load(sys.stdin)["install"]]
print(sum(name.startswith("nvidia") for name in names))' <<<"$report")
  if [ "$nvidia" -gt 0 ]; then
    stop "pip would install a CUDA build of $TORCH_SPEC for $("$VENV/bin/python" -V)" \
      "($nvidia nvidia-* wheels, several GB), not the CPU build; add PyTorch's CPU wheel index" \
      "(PIP_EXTRA_INDEX_URL, see README), install the torch you want for $PYTHON first," \
      "or set ALLOW_CUDA_TORCH=1 to take this one"
  fi
}

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
  created_venv=1
  if "$PYTHON" -c "import torch" >/dev/null 2>&1; then
    echo "setup: using the torch already installed for $PYTHON"
    "$PYTHON" -m venv --system-site-packages "$VENV"
    share_torch_site
  else
    "$PYTHON" -m venv "$VENV"
  fi
fi
if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  echo "setup: no torch found; installing $TORCH_SPEC"
  refuse_cuda_torch
  "$VENV/bin/python" -m pip install -qq "$TORCH_SPEC"
fi
# A torch older than 2.3 was built against numpy 1 and cannot use numpy 2 ("Numpy is not
# available"): keep pip from upgrading numpy past it.
if ! torch_version=$("$VENV/bin/python" -c 'import torch; print(torch.__version__)' 2>/dev/null); then
  stop "the torch in $VENV does not import: $("$VENV/bin/python" -c 'import torch' 2>&1 | tail -1)"
fi
IFS=. read -r major minor _ <<<"$torch_version"
pins=()
if [ "$major" -lt 2 ] || { [ "$major" -eq 2 ] && [ "$minor" -lt 3 ]; }; then
  echo "setup: torch $torch_version predates numpy 2; keeping numpy<2"
  pins=("numpy<2")
fi
"$VENV/bin/python" -m pip install -qq -e ".[dev]" ${pins[@]+"${pins[@]}"}
touch "$stamp"
