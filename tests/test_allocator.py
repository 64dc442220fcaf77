"""keep_freed_memory: large temporaries reuse freed heap memory instead of faulting in fresh
pages on every allocation (Linux with glibc)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

# Faults taken by 20 rounds of allocating, filling and freeing a 48 MB tensor.
ROUNDS = textwrap.dedent(
    """
    import resource, sys
    import torch
    from relaygs.allocator import keep_freed_memory
    if sys.argv[1] == "keep":
        assert keep_freed_memory()
    torch.ones(12 << 20)  # first round: the pages come in once either way
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(20):
        torch.ones(12 << 20)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
    """
)


def _faults(mode: str) -> int:
    done = subprocess.run(
        [sys.executable, "-c", ROUNDS, mode], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return int(done.stdout)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc only")
def test_freed_memory_is_reused_without_page_faults():
    default, kept = _faults("default"), _faults("keep")
    pages = 20 * (48 << 20) // 4096
    assert default > pages // 2  # each round faults its 48 MB in again
    assert kept < default // 2
