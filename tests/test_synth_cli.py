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

from relaygs.commands.synth import main, parse_effect_list
from relaygs.data.synthetic import remove_abandoned_staging


def test_cli_writes_a_scene_with_the_requested_effects(tmp_path: Path, capsys):
    out = tmp_path / "court"
    args = ["court", str(out), "--frames", "2", "--width", "16", "--height", "9", "--seed", "3"]
    assert main([*args, "--effects", "large_motion,nonrigid", "sensor_noise"]) == 0
    declaration = json.loads((out / "scene.json").read_text())
    assert declaration["effects"] == ["large_motion", "nonrigid", "sensor_noise"]
    assert (declaration["frames"], declaration["width"], declaration["seed"]) == (2, 16, 3)
    assert "wrote" in capsys.readouterr().out


def test_effect_list_parsing():
    assert parse_effect_list(None) is None
    assert parse_effect_list([]) == []
    assert parse_effect_list(["a,b", "c"]) == ["a", "b", "c"]


@pytest.mark.parametrize("effects", [["none"], []])
def test_cli_effects_none_or_nothing_writes_a_scene_without_effects(tmp_path: Path, effects):
    out = tmp_path / "juggle"
    args = ["juggle", str(out), "--frames", "1", "--width", "8", "--height", "6"]
    assert main([*args, "--effects", *effects]) == 0
    assert json.loads((out / "scene.json").read_text())["effects"] == []


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["nope"], "unknown preset 'nope'"),
        (["juggle", "--frames", "0"], "frames must be an integer >= 1"),
        (["juggle", "--width", "-3"], "width must be an integer >= 4"),
        (["juggle", "--effects", "wobble"], "unknown effect 'wobble'"),
        (["juggle", "--effects", "none,nonrigid"], "unknown effect 'none'; expected one of"),
        (["static", "--effects", "fast_objects"], "cannot simulate fast_objects"),
    ],
)
def test_cli_bad_input_is_a_single_line_and_exit_2(tmp_path: Path, capsys, args, message):
    assert main([args[0], str(tmp_path / "out"), *args[1:]]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("target", ["scene", "nowhere"])
def test_cli_refuses_a_symbolic_link_as_output(tmp_path: Path, capsys, target):
    (tmp_path / "scene").mkdir()
    link = tmp_path / "link"
    link.symlink_to(tmp_path / target)
    assert main(["static", str(link), "--frames", "1", "--width", "8", "--height", "6"]) == 2
    err = capsys.readouterr().err
    assert err == f"error: output path is a symbolic link: {link}; pass the folder it points to\n"
    assert link.is_symlink() and sorted(p.name for p in tmp_path.iterdir()) == ["link", "scene"]


def test_cli_out_of_memory_is_one_line_and_leaves_no_folder(tmp_path: Path, capsys, monkeypatch):
    def no_memory(*args, **kwargs):
        raise MemoryError

    module = sys.modules["relaygs.data.synthetic.generate"]  # the package exports the function
    monkeypatch.setattr(module, "_write_scene", no_memory)
    assert main(["static", str(tmp_path / "out"), "--width", "30000", "--height", "20000"]) == 1
    err = capsys.readouterr().err
    assert err == "error: not enough memory to render 30000x20000 images: ask for fewer pixels\n"
    assert list(tmp_path.iterdir()) == []


def test_cli_process_exits_nonzero_without_traceback(tmp_path: Path):
    command = [
        sys.executable,
        "-m",
        "relaygs.synth",
        "juggle",
        str(tmp_path / "o"),
        "--height",
        "0",
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == "error: height must be an integer >= 4, got 0"


def test_cli_usage_errors_are_one_line(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["juggle", "out", "--frames", "many"])
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--frames" in lines[0]


@pytest.mark.parametrize(
    ("out", "message"),
    [
        ("/proc/relaygs-synth", "synthetic scene folder: cannot write in /proc ("),
        ("{tmp}/file/out", "synthetic scene folder: {tmp}/file is not a folder"),
    ],
)
def test_cli_an_output_folder_that_cannot_be_written_is_bad_input_exit_2(
    tmp_path: Path, capsys, out, message
):
    # checked before rendering, like the other output-path problems (docs/scenes.md)
    (tmp_path / "file").write_text("mine")
    out, message = out.format(tmp=tmp_path), message.format(tmp=tmp_path)
    assert main(["static", out, "--frames", "1", "--width", "8", "--height", "6"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {message}"), lines


def test_cli_full_disk_is_one_line_and_leaves_no_folder(tmp_path: Path, capsys, monkeypatch):
    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")  # a write's close names no file

    module = sys.modules["relaygs.data.synthetic.generate"]
    monkeypatch.setattr(module, "_write_scene", disk_full)
    out = tmp_path / "out"
    assert main(["static", str(out), "--frames", "1", "--width", "8", "--height", "6"]) == 1
    err = capsys.readouterr().err
    assert err == (
        f"error: No space left on device writing {out}: free space, then rerun the command\n"
    )
    assert list(tmp_path.iterdir()) == []


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
