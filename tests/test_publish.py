"""fsio.publish_bytes (results, summaries, pareto.png): a file appears whole or not at all, is on
disk before it is renamed in, and an error names the file, not the hidden one beside it."""

import errno
import os

import pytest

from relaygs.pipeline import fsio


def _hidden_files(folder):
    return sorted(path.name for path in folder.iterdir() if path.name.startswith("."))


def test_the_data_is_on_disk_before_it_is_renamed_in_and_a_second_writer_keeps_apart(
    tmp_path, monkeypatch
):
    path = tmp_path / "result.json"
    events = []
    real_replace = os.replace

    def replace(source, target):
        events.append(("rename", source.name))
        real_replace(source, target)

    monkeypatch.setattr(fsio, "fsync_path", lambda path: events.append(("fsync", path.name)))
    monkeypatch.setattr(fsio.os, "replace", replace)
    fsio.publish_bytes(path, b"{}")
    partial = f".result.json.{os.getpid()}.partial"
    assert events == [("fsync", partial), ("rename", partial)]
    assert path.read_bytes() == b"{}" and _hidden_files(tmp_path) == []
    monkeypatch.undo()
    # a report and a finishing sweep job both publish the summary; the other process's
    # publish runs between this one's write and its rename
    path = tmp_path / "summary.md"
    real_fsync, pid = fsio.fsync_path, os.getpid()
    other_done = []

    def other_process_publishes_meanwhile(partial):
        real_fsync(partial)
        if not other_done:
            other_done.append(True)
            monkeypatch.setattr(fsio.os, "getpid", lambda: pid + 1)
            fsio.publish_bytes(path, b"other")
            monkeypatch.setattr(fsio.os, "getpid", lambda: pid)

    monkeypatch.setattr(fsio, "fsync_path", other_process_publishes_meanwhile)
    fsio.publish_bytes(path, b"mine")
    assert path.read_bytes() == b"mine" and _hidden_files(tmp_path) == []


def test_a_failed_publish_names_the_file_or_without_an_errno_is_raised_as_it_was(
    tmp_path, monkeypatch
):
    path = tmp_path / "summary.csv"
    (path / "in the way").mkdir(parents=True)  # a folder holding files: no rename onto it
    with pytest.raises(OSError) as raised:
        fsio.publish_text(path, "a,b\n")
    assert raised.value.filename == str(path)
    assert raised.value.errno in (errno.EISDIR, errno.ENOTEMPTY, errno.EEXIST)
    assert _hidden_files(tmp_path) == []
    failure = OSError("the disk went away")  # without an errno: raised as it was

    def fail(path):
        raise failure

    monkeypatch.setattr(fsio, "fsync_path", fail)
    with pytest.raises(OSError) as raised:
        fsio.publish_bytes(tmp_path / "pareto.png", b"png")
    assert raised.value is failure
    assert [path.name for path in tmp_path.iterdir()] == ["summary.csv"]  # no pareto.png
