"""The `python -m relaygs.synth` command: writes a scene; bad input is one stderr line, exit 2."""

from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from relaygs.commands.synth import main
from relaygs.data.synthetic import remove_abandoned_staging


@pytest.mark.parametrize(
    ("effects", "declared"),
    [
        (["large_motion,nonrigid", "sensor_noise"], ["large_motion", "nonrigid", "sensor_noise"]),
        (["none"], []),
        ([], []),
    ],
)
def test_cli_writes_a_scene_with_the_requested_effects(tmp_path: Path, capsys, effects, declared):
    out = tmp_path / "court"
    args = ["court", str(out), "--frames", "2", "--width", "16", "--height", "9", "--seed", "3"]
    assert main([*args, "--effects", *effects]) == 0
    declaration = json.loads((out / "scene.json").read_text())
    assert declaration["effects"] == declared
    assert (declaration["frames"], declaration["width"], declaration["seed"]) == (2, 16, 3)
    assert "wrote" in capsys.readouterr().out


SMALL = ["--frames", "1", "--width", "8", "--height", "6"]


def _refused(capsys, argv: list, code: int, *named: str) -> None:
    """`main(argv)` exits with `code` and one stderr line naming each of `named`."""
    assert main([str(arg) for arg in argv]) == code
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert not [name for name in named if name not in err], err


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        ("nope {tmp}/out", ["'nope'"]),
        ("juggle {tmp}/out --frames 0", ["frames", "1"]),
        ("juggle {tmp}/out --width -3", ["width", "4"]),
        ("juggle {tmp}/out --height 0", ["height", "4", "0"]),
        ("juggle {tmp}/out --effects wobble", ["'wobble'"]),
        ("juggle {tmp}/out --effects none,nonrigid", ["'none'"]),
        ("static {tmp}/out --effects fast_objects", ["fast_objects"]),
        # output folders that cannot be written: checked before rendering (docs/scenes.md)
        ("static /proc/relaygs-synth", ["/proc"]),
        ("static {tmp}/file/out", ["{tmp}/file", "not a folder"]),
    ],
)
def test_cli_bad_input_is_a_single_line_and_exit_2(tmp_path: Path, capsys, argv, named):
    (tmp_path / "file").write_text("mine")
    words = argv.format(tmp=tmp_path).split()
    _refused(capsys, words, 2, *(name.format(tmp=tmp_path) for name in named))
    assert sorted(path.name for path in tmp_path.iterdir()) == ["file"]


@pytest.mark.parametrize("target", ["scene", "nowhere"])
def test_cli_refuses_a_symbolic_link_as_output(tmp_path: Path, capsys, target):
    (tmp_path / "scene").mkdir()
    link = tmp_path / "link"
    link.symlink_to(tmp_path / target)
    _refused(capsys, ["static", link, *SMALL], 2, str(link), "symbolic link")
    assert link.is_symlink() and sorted(p.name for p in tmp_path.iterdir()) == ["link", "scene"]


@pytest.mark.parametrize(
    ("error", "size", "named"),
    [
        (MemoryError(), ["--width", "30000", "--height", "20000"], ["memory", "30000x20000"]),
        # a write's close names no file: the line names the scene folder
        (OSError(errno.ENOSPC, "No space left on device"), SMALL, ["No space", "{out}"]),
    ],
)
def test_cli_out_of_memory_or_disk_is_one_line_and_leaves_no_folder(
    tmp_path: Path, capsys, monkeypatch, error, size, named
):
    def fail(*args, **kwargs):
        raise error

    module = sys.modules["relaygs.data.synthetic.generate"]  # the package exports the function
    monkeypatch.setattr(module, "_write_scene", fail)
    out = tmp_path / "out"
    _refused(capsys, ["static", out, *size], 1, *(name.format(out=out) for name in named))
    assert list(tmp_path.iterdir()) == []


def test_cli_usage_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["juggle", "out", "--frames", "many"])
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--frames" in lines[0]


def _staging_leftovers(out: Path) -> list[str]:
    return sorted(path.name for path in out.parent.glob(f".{out.name}.partial-*"))


def test_a_generation_killed_midway_leaves_no_staging_folder_once_run_again(tmp_path: Path):
    out = tmp_path / "scene"
    args = ["court", str(out), "--frames", "64", "--width", "160", "--height", "90"]
    code = f"from relaygs.commands.synth import main; main({args!r})"
    writer = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 120
        while not _staging_leftovers(out) and writer.poll() is None:
            assert time.monotonic() < deadline, "the generation never started writing"
            time.sleep(0.05)
    finally:
        writer.kill()
        writer.wait()
    assert _staging_leftovers(out) and not out.exists()  # killed while it wrote
    assert main(["static", str(out), "--frames", "1", "--width", "8", "--height", "6"]) == 0
    assert _staging_leftovers(out) == [] and (out / "scene.json").is_file()


def test_staging_of_a_running_or_unknown_writer_is_left_unless_the_caller_holds_the_lock(
    tmp_path: Path,
):
    out = tmp_path / "scene"
    running = tmp_path / f".scene.partial-{socket.gethostname()}-{os.getpid()}"
    elsewhere = tmp_path / ".scene.partial-another-host-12"
    for folder in (running, elsewhere):
        folder.mkdir()
    remove_abandoned_staging(out)
    assert _staging_leftovers(out) == sorted([running.name, elsewhere.name])
    remove_abandoned_staging(out, any_writer=True)
    assert _staging_leftovers(out) == []
