"""usable_device: the CPU always, CUDA only where this torch can allocate, nothing else; timers
wait for the device."""

from types import SimpleNamespace

import pytest
import torch

from relaygs.commands import bench, bench_splat
from relaygs.device import synchronize, usable_device
from relaygs.errors import InputError


def test_cpu_is_always_usable() -> None:
    assert usable_device("cpu", "train.device") == torch.device("cpu")


@pytest.mark.parametrize("name", ["warp-drive", "meta", "mps:0"])
def test_devices_the_core_does_not_run_on_are_refused(name: str) -> None:
    with pytest.raises(
        InputError, match=rf"^train\.device: expected 'cpu', 'cuda' or 'cuda:N', got '{name}'$"
    ):
        usable_device(name, "train.device")


def test_an_unusable_cuda_device_is_named_with_the_reason() -> None:
    # No CUDA here: plain "cuda" is unusable; with GPUs, the index one past the last one.
    name = f"cuda:{torch.cuda.device_count()}" if torch.cuda.is_available() else "cuda"
    with pytest.raises(InputError, match=rf"^--device: cannot use '{name}' here \(.+\)$"):
        usable_device(name, "--device")


def test_bench_refuses_a_bad_device_before_timing(monkeypatch, capsys) -> None:
    monkeypatch.setattr(bench_splat, "bench_splat", lambda *args: pytest.fail("benchmark started"))
    assert bench.main(["splat", "--device", "meta"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: --device: expected 'cpu', 'cuda' or 'cuda:N', got 'meta'"
    )


def test_synchronize_waits_for_a_cuda_device_only(monkeypatch) -> None:
    waited = []
    monkeypatch.setattr(torch.cuda, "synchronize", waited.append)
    synchronize(torch.device("cpu"))
    synchronize(torch.device("cuda", 1))
    assert waited == [torch.device("cuda", 1)]


def test_bench_times_each_run_until_the_device_has_finished(monkeypatch) -> None:
    events: list[str] = []
    monkeypatch.setattr(bench_splat, "synchronize", lambda device: events.append(f"sync {device}"))
    clock = SimpleNamespace(perf_counter=lambda: events.append("clock") or 0.0)
    monkeypatch.setattr(bench_splat, "time", clock)
    bench_splat._median_ms(lambda: events.append("run"), 2, torch.device("cpu"))
    assert events == ["run"] + ["sync cpu", "clock", "run", "sync cpu", "clock"] * 2
