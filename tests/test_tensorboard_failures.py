"""A TensorBoard log that cannot be written (a full disk, a folder removed while the job runs)
ends the job in one line naming the log folder, without the writer thread's traceback."""

import errno
import os
import shutil
from pathlib import Path

import pytest

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
