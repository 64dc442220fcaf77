"""Progress bars: live in a terminal, throttled when written to a log file."""

from __future__ import annotations

import io

from conftest import WriteRecorder
from relaygs.progress import (
    LOG_INTERVAL_S,
    is_terminal,
    job_label,
    labelled,
    print_labelled,
    progress_bar,
)


class _Terminal(io.StringIO):
    """A text stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


class _Clock:
    """A clock that moves one second each time it is read: 200 updates span minutes."""

    def __init__(self, start: float) -> None:
        self.now = start

    def __call__(self) -> float:
        self.now += 1.0
        return self.now


def _records(stream: io.StringIO, updates: int) -> int:
    """Carriage-return records written by a bar over `updates` updates a second or more apart."""
    with progress_bar(total=updates, stream=stream) as bar:
        bar._time = _Clock(bar.last_print_t)  # tqdm reads its clock through this attribute
        for _ in range(updates):
            bar.update(1)
    return stream.getvalue().count("\r")


def test_a_logged_bar_redraws_every_half_minute_where_a_live_one_redraws_each_second(
    monkeypatch,
) -> None:
    with progress_bar(total=10, stream=io.StringIO()) as logged:
        assert logged.mininterval == logged.maxinterval == LOG_INTERVAL_S
    with progress_bar(total=10, stream=_Terminal()) as live:
        assert live.mininterval < 1.0  # tqdm's own
    closed = io.StringIO()
    closed.close()
    assert not is_terminal(closed) and not is_terminal(io.StringIO()) and is_terminal(_Terminal())
    logged, live = _records(io.StringIO(), 200), _records(_Terminal(), 200)
    assert 3 <= logged <= 2 * 200 / LOG_INTERVAL_S + 3  # still alive, but sparse
    assert live >= 100
    # a job label leads lines and bar names only inside its block
    with job_label("3_k64"):
        assert labelled("[relay] built") == "[3_k64] [relay] built"
        with progress_bar(total=2, desc="relay", stream=io.StringIO()) as bar:
            assert bar.desc.startswith("3_k64 relay")
        with job_label(None):  # a job run alone inside it names nothing
            assert labelled("[relay] built") == "[relay] built"
        assert labelled("x") == "[3_k64] x"
        assert labelled("outputs:\n  result r.json") == "[3_k64] outputs:\n[3_k64]   result r.json"
    assert labelled("[relay] built") == "[relay] built"
    assert labelled("outputs:\n  result r.json") == "outputs:\n  result r.json"
    with progress_bar(total=2, desc="relay", stream=io.StringIO()) as bar:
        assert bar.desc.startswith("relay")
    # a labelled block is one write: another job's lines cannot land inside it
    stdout = WriteRecorder()
    monkeypatch.setattr("sys.stdout", stdout)
    with job_label("3_k64"):
        print_labelled("PSNR 30\noutputs:")
    print_labelled("PSNR 30\noutputs:")
    assert stdout.writes == ["[3_k64] PSNR 30\n[3_k64] outputs:\n", "PSNR 30\noutputs:\n"]
