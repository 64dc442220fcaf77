"""tools/gpu_check.sh's plumbing, without a GPU: each step runs under its limit into one table,
a failing step does not stop the others, and the exit code says whether all passed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from relaygs import paths

SCRIPT = paths.REPO_ROOT / "tools" / "gpu_check.sh"
STEPS = ("env", "parity", "splat", "job", "train", "profile")


@pytest.mark.skipif(not SCRIPT.is_file(), reason="needs the repository's tools/")
def test_every_step_lands_in_one_table_and_a_failure_fails_the_script(tmp_path):
    # A Python that fails every step at once (exit 3) but runs the summary it is fed on stdin.
    python = tmp_path / "python"
    python.write_text(
        f'#!/bin/sh\nif [ "$1" = "-" ]; then exec {sys.executable} "$@"; fi\n'
        'echo "step output: $*"\nexit 3\n'
    )
    python.chmod(0o755)
    report = tmp_path / "report"
    done = subprocess.run(
        ["bash", str(SCRIPT), str(report)],
        capture_output=True,
        text=True,
        env={
            **os.environ,
            "PYTHON": str(python),
            "WORK": str(tmp_path / "work"),
            "WHEELS": str(tmp_path),
        },
        timeout=120,
    )
    assert done.returncode != 0, done.stdout
    rows = [line.split(" | ") for line in (report / "summary.md").read_text().splitlines()[2:]]
    assert [row[0].lstrip("| ") for row in rows] == list(STEPS)
    assert all(row[1] == "failed (3)" for row in rows), rows
    job = rows[STEPS.index("job")]
    assert "step output: -m relaygs.run train.device=cuda" in job[3]
    assert "tools/gpu_profile.py --device cuda --backend triton" in rows[-1][3]
    assert Path(report / "logs.txt").is_file()
    assert Path(report / "logs.tgz").is_file()
