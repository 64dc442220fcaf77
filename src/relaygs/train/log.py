"""Live training metrics: stages `emit` scalars and images to the sinks the app attaches."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from torch import Tensor

Sink = Callable[[str, int, Mapping[str, float], Mapping[str, Tensor] | None], None]

_SINKS: list[Sink] = []


def add_sink(sink: Sink) -> None:
    """Start sending every emitted record to `sink` (adding the same sink twice is a no-op)."""
    if sink not in _SINKS:
        _SINKS.append(sink)


def remove_sink(sink: Sink) -> None:
    """Stop sending records to `sink` (a sink that was never added is ignored)."""
    if sink in _SINKS:
        _SINKS.remove(sink)


def emit(
    stage: str, step: int, scalars: Mapping[str, float], images: Mapping[str, Tensor] | None = None
) -> None:
    """Send one record to every sink: scalar metrics and optional [H,W,3] images in [0,1]."""
    for sink in list(_SINKS):
        sink(stage, step, scalars, images)
