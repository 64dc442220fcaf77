"""A TensorBoard log that cannot be written (a full disk, a folder removed while the job runs)
ends the job in one line naming the log folder, without the writer thread's traceback."""

import errno
import os
import shutil
import threading
from pathlib import Path

import pytest
import torch

from relaygs.app.tensorboard import TensorBoardLog
from relaygs.errors import ResourceError, resource_error

QUIET_THREAD = "error::pytest.PytestUnhandledThreadExceptionWarning"


@pytest.mark.filterwarnings(QUIET_THREAD)
def test_a_log_folder_removed_while_the_job_runs_is_one_resource_error(tmp_path: Path):
    log = TensorBoardLog(tmp_path / "tb")
    log("decouple", 0, {"loss": 1.0})
    log.writer.flush()
    shutil.rmtree(tmp_path / "tb")
    with pytest.raises(ResourceError, match=f"TensorBoard log folder {tmp_path}/tb was removed"):
        log("decouple", 1, {"loss": 0.5})
        log.close()
    log.close()  # releasing the failed writer raises nothing more


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux)")
@pytest.mark.filterwarnings(QUIET_THREAD)
def test_a_full_disk_under_the_log_names_its_folder(tmp_path: Path):
    log = TensorBoardLog(tmp_path / "tb")
    (event_file,) = (tmp_path / "tb").iterdir()
    event_file.unlink()
    event_file.symlink_to("/dev/full")  # every write fails with ENOSPC
    with pytest.raises(OSError) as raised:
        log("decouple", 0, {"loss": 1.0})
        log.close()
    assert raised.value.errno == errno.ENOSPC
    message = str(resource_error(raised.value, "stage decouple"))
    assert message.startswith(f"stage decouple: No space left on device writing {tmp_path}/tb:")


@pytest.mark.parametrize("errno_", [errno.ENOSPC, None])
def test_a_failed_write_names_the_log_folder_or_without_an_errno_is_raised_as_it_was(
    tmp_path: Path, monkeypatch, errno_
):
    log = TensorBoardLog(tmp_path / "tb")
    failure = OSError(errno_, "No space left on device") if errno_ else OSError("thread gone")

    def fail(*args, **kwargs):
        raise failure

    monkeypatch.setattr(log.writer, "add_image", fail)
    with pytest.raises(OSError) as raised:
        log("decouple", 0, {}, images={"render": torch.zeros(2, 3, 3)})
    if errno_:
        assert (raised.value.errno, raised.value.filename) == (errno_, str(tmp_path / "tb"))
    else:
        assert raised.value is failure
    log.close()  # releasing the failed writer raises nothing more


class _WriterThread(threading.Thread):
    """Stands for TensorBoard's event-writer thread (told apart by its class's module)."""


_WriterThread.__module__ = "tensorboard.summary.writer.event_file_writer"


def _raise_in(thread_class: type[threading.Thread], error: BaseException) -> None:
    def fail() -> None:
        raise error

    thread = thread_class(target=fail)
    thread.start()
    thread.join()


def test_only_the_writer_threads_os_errors_go_unprinted(tmp_path: Path, monkeypatch):
    seen = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_value))
    TensorBoardLog(tmp_path / "a").close()
    TensorBoardLog(tmp_path / "b").close()  # the hook goes in once, not once per log
    hook = threading.excepthook
    assert not isinstance(hook.previous, type(hook))
    dropped, other_thread, other_error = OSError(errno.ENOSPC, "full"), OSError(1), KeyError(2)
    _raise_in(_WriterThread, dropped)  # raised again at the job's next call
    _raise_in(threading.Thread, other_thread)
    _raise_in(_WriterThread, other_error)
    assert seen == [other_thread, other_error]
