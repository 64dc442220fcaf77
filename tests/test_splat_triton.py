"""The Triton kernels without a GPU: their interpreter tests (tests/splat_triton_cases.py), run
in a child pytest with TRITON_INTERPRET=1 (triton reads it once, when first imported, so
setting it here would put every later test of this process in the interpreter too), and
their compilation for a Hopper GPU."""

from __future__ import annotations

import importlib.util
import inspect
import os
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest
import torch

CASES = Path(__file__).with_name("splat_triton_cases.py")


@pytest.mark.skipif(
    importlib.util.find_spec("triton") is None,
    reason="triton is not installed (the dev extra brings it)",
)
def test_the_triton_kernels_pass_their_interpreter_tests():
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(CASES)],
        capture_output=True,
        text=True,
        env={**os.environ, "TRITON_INTERPRET": "1"},
        cwd=CASES.parent.parent,
        timeout=600,
    )
    report = done.stdout[-6000:] + done.stderr[-2000:]
    assert done.returncode == 0, report
    summary = done.stdout.strip().splitlines()[-1]
    passed = re.search(r"(\d+) passed", summary)
    assert passed and int(passed.group(1)) >= 30 and "skipped" not in summary, report


# Argument types of the kernels for float32 renders; the rest are i32 scalars or constexpr.
INDEX_ARGS = {"pairs": "*i64", "tile_start": "*i64", "tile_count": "*i64", "tiles": "*i64"}
INT_OUTPUTS = {"last": "*i32", "radii": "*i32", "bounds": "*i32", "visible_out": "*i8"}
SCALAR_ARGS = ("tile_size", "tiles_x", "tiles_y", "width", "height", "channels", "n", "cams")
needs_triton = pytest.mark.skipif(
    importlib.util.find_spec("triton") is None,
    reason="triton is not installed (the dev extra brings it)",
)


def _compile_for_sm90(fn, constexprs: dict, tmp_path: Path, monkeypatch) -> dict:
    """`fn` compiled to sm_90 machine code with float32 pointers (no GPU needed): its asm."""
    monkeypatch.setenv("TRITON_CACHE_DIR", str(tmp_path))  # compile, not a cached result
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    from relaygs.splat.triton import composite

    signature = {
        name: "constexpr"
        if name in constexprs
        else {**INDEX_ARGS, **INT_OUTPUTS}.get(name, "i32" if name in SCALAR_ARGS else "*fp32")
        for name in inspect.signature(fn.fn).parameters
    }
    compiled = triton.compile(
        ASTSource(fn=fn, signature=signature, constexprs=constexprs),
        target=GPUTarget("cuda", 90, 32),
        options=composite.COMPILE_OPTIONS,
    )
    assert b".target sm_90" in compiled.asm["ptx"].encode() and len(compiled.asm["cubin"]) > 0
    return compiled.asm


@needs_triton
@pytest.mark.parametrize("channels", [3, 32])
@pytest.mark.parametrize("kernel", ["composite_forward_kernel", "composite_backward_kernel"])
def test_the_kernels_compile_for_a_hopper_gpu_without_one(kernel, channels, tmp_path, monkeypatch):
    """Triton's compiler, unlike its interpreter, refuses what a GPU cannot run (globals that
    are not constexpr, loop-carried values that change type) and rewrites what it recognises:
    compile to sm_90 machine code with the block sizes of an 8×8-tile render, and find no
    matrix product in it (one made of the colour sum composited 32 channels wrongly on a GPU,
    which the interpreter cannot show)."""
    from relaygs.splat.triton import composite, kernels

    elements = composite.FORWARD_ELEMENTS if "forward" in kernel else composite.BACKWARD_ELEMENTS
    bins = types.SimpleNamespace(tile_size=8)
    sizes = composite.launch_for(bins, torch.zeros(1), channels, elements).sizes()
    asm = _compile_for_sm90(getattr(kernels, kernel), sizes, tmp_path, monkeypatch)
    assert "tt.dot" not in asm["ttir"]


@needs_triton
@pytest.mark.parametrize("kernel", ["project_forward_kernel", "project_backward_kernel"])
def test_the_projection_kernels_compile_for_a_hopper_gpu_without_one(kernel, tmp_path, monkeypatch):
    from relaygs.splat.triton import project_kernels, projection

    fn = getattr(project_kernels, kernel)
    _compile_for_sm90(fn, {"BLOCK": projection.BLOCK}, tmp_path, monkeypatch)
