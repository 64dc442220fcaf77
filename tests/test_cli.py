"""Command-line plumbing shared by the tools: their start, Ctrl-C, and output into a pipe
whose reader went away."""

import importlib
import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import relaygs
from relaygs.__main__ import COMMANDS
from relaygs.cli import BROKEN_PIPE_EXIT, INTERRUPTED_EXIT, start_tool
from relaygs.shell import python_command

LONG_OUTPUT = (
    "import sys; from relaygs.cli import run_tool; sys.exit(run_tool(lambda: print('x' * 99)))"
)


def _closed_reader(args: list[str], buffered: bool = False) -> tuple[int, str]:
    """Run `args` with its stdout a pipe closed before it writes: (exit status, stderr); with
    `buffered`, its stdout is block-buffered whatever PYTHONUNBUFFERED says here."""
    env = {k: v for k, v in os.environ.items() if not (buffered and k == "PYTHONUNBUFFERED")}
    process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    process.stdout.close()
    with process.stderr:
        stderr = process.stderr.read().decode()
    return process.wait(timeout=120), stderr


@pytest.mark.parametrize(
    ("command", "buffered"), [("artifacts", False), ("run_tool", False), ("run_tool", True)]
)
def test_a_reader_that_closed_the_pipe_ends_the_tool_quietly(tmp_path, command, buffered):
    # `python -m relaygs.artifacts ls | head`: before, a BrokenPipeError traceback (and
    # "Exception ignored ... BrokenPipeError" when the interpreter flushed stdout at exit);
    # block-buffered stdout (no PYTHONUNBUFFERED) fails only when flushed, at the tool's end
    if command == "artifacts":
        args = ["-m", "relaygs.artifacts", "--root", str(tmp_path), "ls"]
    else:
        args = ["-c", LONG_OUTPUT]
    assert BROKEN_PIPE_EXIT == 128 + 13  # the shell's 128 + SIGPIPE
    assert _closed_reader([sys.executable, *args], buffered) == (BROKEN_PIPE_EXIT, "")


TOOLS = tuple(name for name, _ in COMMANDS)


def test_python_m_relaygs_lists_every_command_it_has_an_entry_module_for():
    entries = {
        path.stem
        for path in Path(relaygs.__file__).parent.glob("*.py")
        if 'start_tool("relaygs.commands.' in path.read_text()
    }
    assert entries == set(TOOLS)
    listed = subprocess.run([sys.executable, "-m", "relaygs"], capture_output=True, text=True)
    assert listed.returncode == 0
    assert [line.split()[2] for line in listed.stdout.splitlines()[1:]] == [
        f"relaygs.{tool}" for tool in TOOLS
    ]


@pytest.mark.parametrize(
    ("argv", "start"),
    [(["run", "seed=1"], "python -m relaygs.run ..."), (["nope"], "python -m relaygs.NAME")],
)
def test_python_m_relaygs_with_arguments_is_a_usage_error_not_a_silent_success(argv, start):
    # `python -m relaygs run ...` in a script must not exit 0 having run nothing
    command = [sys.executable, "-m", "relaygs", *argv]
    called = subprocess.run(command, capture_output=True, text=True)
    assert (called.returncode, called.stdout) == (2, "")
    assert called.stderr.startswith("error: ") and start in called.stderr
    assert called.stderr.count("\n") == 1


def test_the_entry_modules_load_nothing_heavy():
    # `python -m relaygs.X` runs relaygs/X.py before anything can catch a Ctrl-C: it must not
    # import torch or Hydra itself (one to three seconds), or a Ctrl-C then is a traceback
    imports = "; ".join(f"import relaygs.{tool}" for tool in TOOLS)
    heavy = "[name for name in ('torch', 'hydra', 'numpy', 'pandas') if name in sys.modules]"
    script = f"import sys; {imports}; print({heavy})"
    loaded = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert (loaded.returncode, loaded.stdout.strip()) == (0, "[]"), loaded.stderr


@pytest.mark.parametrize("tool", TOOLS)
def test_each_entry_module_starts_its_command(tool):
    started = subprocess.run(
        [sys.executable, "-m", f"relaygs.{tool}", "--help"], capture_output=True, text=True
    )
    assert started.returncode == 0 and f"python -m relaygs.{tool}" in started.stdout, started.stderr


def _tool_module(tmp_path, monkeypatch, body: str) -> str:
    """A throwaway tool module on sys.path whose source is `body`; returns its name."""
    name = f"tool_{tmp_path.name}"
    (tmp_path / f"{name}.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    return name


@pytest.mark.parametrize(
    ("body", "status", "out", "err"),
    [
        ("raise KeyboardInterrupt  # while importing", INTERRUPTED_EXIT, "", "interrupted\n"),
        ("def main():\n    raise KeyboardInterrupt", INTERRUPTED_EXIT, "", "interrupted\n"),
        ("def main():\n    print('ran')\n    return 3", 3, "ran\n", ""),
    ],
)
def test_a_started_tool_exits_with_its_mains_status_or_one_line_on_ctrl_c(
    tmp_path, monkeypatch, capsys, body, status, out, err
):
    with pytest.raises(SystemExit) as stop:
        start_tool(_tool_module(tmp_path, monkeypatch, body))
    assert (stop.value.code, *capsys.readouterr()) == (status, out, err)
    # once its work is done, a Ctrl-C during the interpreter's shutdown changes nothing
    # (conftest's sigint_handler_restored undoes it for the tests that follow)
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_a_tools_output_its_terminal_cannot_encode_is_escaped_not_a_traceback(tmp_path):
    (tmp_path / "greek_tool.py").write_text("def main():\n    print('Δ PSNR ↑')\n    return 0\n")
    path = os.pathsep.join(filter(None, [str(tmp_path), os.environ.get("PYTHONPATH")]))
    env = os.environ | {"PYTHONIOENCODING": "ascii", "PYTHONPATH": path}
    started = subprocess.run(
        [sys.executable, "-c", "from relaygs.cli import start_tool; start_tool('greek_tool')"],
        env=env,
        capture_output=True,
    )
    assert (started.returncode, started.stdout) == (0, b"\\u0394 PSNR \\u2191\n"), started.stderr


def test_printed_commands_start_python_as_this_shell_would_find_it(tmp_path, monkeypatch):
    here = Path(sys.executable).absolute()
    monkeypatch.setenv("PATH", f"{here.parent}{os.pathsep}/usr/bin")
    if (here.parent / "python").exists():
        assert python_command() == "python"  # an activated venv: `python` is this one
    monkeypatch.setenv("PATH", str(tmp_path))  # `python` finds another or none
    assert shlex.split(python_command()) == [str(here)]


def test_a_python_of_another_kind_in_the_same_folder_is_not_taken_for_this_one(
    tmp_path, monkeypatch
):
    other = tmp_path / "python"  # e.g. /usr/bin/python → python2 beside /usr/bin/python3
    other.write_text("#!/bin/sh\necho python2\n")
    other.chmod(0o755)
    (tmp_path / "python3").symlink_to(Path(sys.executable).resolve())
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python3"))
    monkeypatch.setenv("PATH", str(tmp_path))
    assert python_command() == shlex.quote(str(tmp_path / "python3"))


@pytest.mark.parametrize(
    ("module", "argv"),
    [
        ("artifacts", ["--root", "", "ls"]),
        ("artifacts", ["render", "abcd", "--scene", "s", "--out", " "]),
        ("artifacts", ["eval", "abcd", "--scene", ""]),
        ("report", [""]),
        ("synth", ["juggle", ""]),
        ("frames", ["videos", ""]),
    ],
)
def test_an_empty_path_is_a_usage_error_not_the_current_folder(module, argv, capsys):
    # Path("") is ".": `render --out ''` wrote (and replaced) frames in the current folder
    main = importlib.import_module(f"relaygs.commands.{module}").main
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected a path, got" in err
