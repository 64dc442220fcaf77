"""The Triton kernels' interpreter tests (tests/splat_triton_cases.py), run in a child pytest
with TRITON_INTERPRET=1: triton reads it once, when first imported, so setting it here would
put every later test of this process in the interpreter too."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

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
