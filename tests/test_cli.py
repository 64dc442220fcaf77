"""Command-line plumbing shared by the tools: output into a pipe whose reader went away."""

import os
import subprocess
import sys

import pytest

from relaygs.cli import BROKEN_PIPE_EXIT

LONG_OUTPUT = (
    "import sys; from relaygs.cli import run_tool; sys.exit(run_tool(lambda: print('x' * 99)))"
)


def _closed_reader(args: list[str], buffered: bool = False) -> tuple[int, str]:
    """Run `args` with its stdout a pipe closed before it writes: (exit status, stderr); with
    `buffered`, its stdout is block-buffered whatever PYTHONUNBUFFERED says here."""
    env = {k: v for k, v in os.environ.items() if not (buffered and k == "PYTHONUNBUFFERED")}
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    process.stdout.close()
    stderr = process.stderr.read().decode()
    return process.wait(timeout=120), stderr


@pytest.mark.parametrize("command", ["artifacts", "run_tool"])
def test_a_reader_that_closed_the_pipe_ends_the_tool_quietly(tmp_path, command):
    # `python -m relaygs.artifacts ls | head`: before, a BrokenPipeError traceback (and
    # "Exception ignored ... BrokenPipeError" when the interpreter flushed stdout at exit)
    if command == "artifacts":
        args = ["-m", "relaygs.artifacts", "--root", str(tmp_path), "ls"]
    else:
        args = ["-c", LONG_OUTPUT]
    assert _closed_reader([sys.executable, *args]) == (BROKEN_PIPE_EXIT, "")


def test_buffered_output_that_meets_a_closed_pipe_at_the_end_is_quiet_too():
    # with block-buffered stdout (no PYTHONUNBUFFERED) the write fails only when it is flushed:
    # at the tool's end, not at exit ("Exception ignored ... BrokenPipeError", status 120)
    assert _closed_reader([sys.executable, "-c", LONG_OUTPUT], buffered=True) == (141, "")


def test_the_broken_pipe_status_is_the_shells_128_plus_sigpipe():
    assert BROKEN_PIPE_EXIT == 128 + 13 == 141
