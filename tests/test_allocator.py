"""keep_freed_memory: a freed large temporary stays in the heap for the next one instead of
going back to the kernel (to be faulted in again), on Linux with glibc."""

import ctypes
import subprocess
import sys
import textwrap

import pytest

# The releasable heap top glibc keeps (mallinfo2().keepcost) after one 16 MB tensor is freed:
# once, as glibc's defaults raise their mmap threshold after the first such free.
KEPT_TOP = textwrap.dedent(
    """
    import ctypes, sys
    import torch
    from relaygs.allocator import keep_freed_memory

    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
            "uordblks", "fordblks", "keepcost")]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    torch.ones(4 << 20)
    print(libc.mallinfo2().keepcost)
    """
)


def _kept_top(mode: str) -> int:
    done = subprocess.run(
        [sys.executable, "-c", KEPT_TOP, mode], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return int(done.stdout)


def _has_mallinfo2() -> bool:
    try:
        return hasattr(ctypes.CDLL("libc.so.6"), "mallinfo2")
    except OSError:
        return False


@pytest.mark.skipif(not _has_mallinfo2(), reason="glibc >= 2.33 only")
def test_freed_memory_stays_in_the_heap():
    assert _kept_top("keep") >= 16 << 20
    assert _kept_top("default") < 16 << 20  # glibc's defaults hand it back
