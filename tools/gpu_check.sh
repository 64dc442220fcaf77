#!/usr/bin/env bash
# The GPU path's check on one CUDA machine, end to end in under 10 minutes, each step under
# its own time limit (550 s in all, the most telling first): the CUDA parity tests (Triton
# kernels and torch on the GPU against the reference and the CPU), `bench splat` of torch
# against triton, the default job on CUDA, `bench train` of both backends and a profile of
# each stage's steps (tools/gpu_profile.py: launches and host reads per step, how busy the
# GPU is); then one table of what each step gave, with every step's whole log in logs.tgz.
# Rehearsed on a CPU with Triton 3.6 (the CUDA image's): the Triton interpreter tests pass.
#
#   tools/gpu_check.sh [REPORT_DIR]      # default /tmp/gpu_check/report
#
# PYTHON (default python3) must import torch (a CUDA build), triton and relaygs's
# dependencies; wheels in WHEELS (.whl/) are installed first (into /tmp/site, no index), for a
# machine that cannot reach a package index. GARDEN_NPZ names a copy of test_garden.npz for
# bench splat's garden case where ../shared/data has none. REPORT_DIR receives summary.md,
# the benches' JSON, the job's result.json, the steps' log tails and logs.tgz; the work
# itself goes to WORK (/tmp/gpu_check). DEVICE (cuda), BACKENDS (torch,triton) and
# SPLAT_CASES (all) change what is run, to rehearse the script on a CPU. The wheels such a
# machine lacks (hydra-core, omegaconf, antlr4-python3-runtime, hydra-joblib-launcher):
# `pip download` the first three's and the launcher's py3 wheels into .whl/ (antlr4 4.9.3
# is an sdist: `pip wheel --no-deps` it), and carry .whl/ with the tree.
set -uo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
BACKENDS=${BACKENDS:-torch,triton}
SPLAT_CASES=${SPLAT_CASES:-random-2k-256,random-10k-256,random-50k-256,garden}
WORK=${WORK:-/tmp/gpu_check}
REPORT=${1:-$WORK/report}
rm -rf "$WORK/outputs" "$WORK/logs"
mkdir -p "$REPORT" "$WORK/logs"
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
WHEELS=${WHEELS:-.whl}
if compgen -G "$WHEELS/*.whl" >/dev/null; then
  "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site "$WHEELS"/*.whl || { echo "gpu_check: installing $WHEELS failed"; exit 2; }
  export PYTHONPATH="$PYTHONPATH:/tmp/site"
fi
if [ -f "${GARDEN_NPZ:-}" ] && [ ! -f ../shared/data/test_garden.npz ]; then
  mkdir -p ../shared/data && cp "$GARDEN_NPZ" ../shared/data/
fi
STEPS="$WORK/steps.tsv"
: >"$STEPS"

# step NAME SECONDS COMMAND...: run COMMAND under a time limit, log to $WORK/logs/NAME.log,
# record NAME, ok/failed (exit code)/timed out, and its seconds.
step() {
  local name=$1 limit=$2
  shift 2
  local began=$SECONDS
  echo "== $name (limit ${limit}s): $*"
  timeout --kill-after=5 "$limit" "$@" >"$WORK/logs/$name.log" 2>&1
  local rc=$? status=ok
  if [ $rc -eq 124 ] || [ $rc -eq 137 ]; then status="timed out"; elif [ $rc -ne 0 ]; then
    status="failed ($rc)"
  fi
  printf '%s\t%s\t%s\n' "$name" "$status" "$((SECONDS - began))" >>"$STEPS"
  tail -n 4 "$WORK/logs/$name.log"
}

step env 30 "$PYTHON" -c "import torch, triton, hydra, relaygs.splat
gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'
print('torch', torch.__version__, 'triton', triton.__version__, gpu)"
step parity 100 "$PYTHON" -m pytest -q -p no:cacheprovider -k cuda \
  tests/test_splat_triton_cuda.py tests/test_splat_parity.py tests/test_cuda_stages.py
step splat 60 "$PYTHON" -m relaygs.bench splat --device "$DEVICE" --backends "$BACKENDS" \
  --cases "$SPLAT_CASES" --json "$WORK/splat.json"
step job 200 "$PYTHON" -m relaygs.run "train.device=$DEVICE" train.progress=false \
  "paths.outputs=$WORK/outputs"
step train 80 "$PYTHON" -m relaygs.bench train --device "$DEVICE" --backends "$BACKENDS" \
  --steps 20 --repeats 2 --cache "$WORK/cache" --json "$WORK/train.json"
step profile 80 "$PYTHON" tools/gpu_profile.py --device "$DEVICE" --backend "${BACKENDS##*,}" \
  --steps 20 --cache "$WORK/cache"

RESULT=$(find "$WORK/outputs/runs" -name result.json 2>/dev/null | head -n 1)
"$PYTHON" - "$STEPS" "$WORK" "${RESULT:-}" >"$REPORT/summary.md" <<'EOF'
"""One Markdown table: each step's status and seconds, and what it measured."""
import json
import sys
from pathlib import Path

steps, work, result = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]


def read(path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def splat_figures(report):
    cells = []
    for case in report["cases"]:
        (first, a), (second, b) = list(case["backends"].items())[:2]
        cells.append(
            f"{case['name']}: f+b {first} {a['fwd_bwd_ms']:.1f} ms, {second} "
            f"{b['fwd_bwd_ms']:.2f} ms ({a['fwd_bwd_ms'] / b['fwd_bwd_ms']:.1f}×), fwd "
            f"{second} {b['fwd_ms']:.2f} ms"
        )
    return "; ".join(cells)


def train_figures(report):
    stages = report["stages"]
    rows = zip(*(stages[name] for name in report["backends"]))
    return "; ".join(
        f"{row[0]['stage']} " + " / ".join(f"{r['steps_per_s']:.1f}" for r in row) + " steps/s"
        for row in rows
    ) + f" ({' / '.join(report['backends'])})"


def job_figures(report):
    return (
        f"train {report['train_s_total']:.1f} s, eval {report['eval_s_total']:.1f} s, "
        f"PSNR {report['psnr']:.2f} dB, SSIM {report['ssim']:.4f}, fg-PSNR "
        f"{report['fg_psnr']:.2f} dB, {report['num_gaussians']} Gaussians, "
        f"backend {report.get('splat.backend')}"
    )


figures = {
    "splat": (read(work / "splat.json"), splat_figures),
    "train": (read(work / "train.json"), train_figures),
    "job": (read(result) if result else None, job_figures),
}
print("| step | status | s | figures |")
print("|---|---|---:|---|")
for line in steps.read_text().splitlines():
    name, status, seconds = line.split("\t")
    report, describe = figures.get(name, (None, None))
    try:
        text = describe(report) if report else ""
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as error:
        text = f"(unreadable: {error!r})"
    if name in ("env", "parity") or not text:
        log = (work / "logs" / f"{name}.log").read_text(errors="replace").strip().splitlines()
        text = text or (log[-1] if log else "")
    print(f"| {name} | {status} | {seconds} | {text.replace('|', '/')} |")
EOF
cat "$REPORT/summary.md"
cp "$WORK/splat.json" "$WORK/train.json" "$REPORT/" 2>/dev/null
[ -n "${RESULT:-}" ] && cp "$RESULT" "$REPORT/result.json"
tail -n 40 "$WORK"/logs/*.log >"$REPORT/logs.txt"
tar -czf "$REPORT/logs.tgz" -C "$WORK" logs
! grep -qv $'\tok\t' "$STEPS"
