"""The settings a sweep varies, read back from Hydra's record, for the job's HParams."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from relaygs.app.prelaunch import parse_overrides, recorded_jobs, swept_keys


@dataclass(frozen=True)
class SweepAxes:
    """Each swept key with the values the sweep gives it, in job order, and this job's value."""

    domains: dict[str, list[Any]] = field(default_factory=dict)
    values: dict[str, Any] = field(default_factory=dict)


def sweep_axes(jobs: Sequence[Sequence[str]], job: Sequence[str]) -> SweepAxes:
    """The axes of the sweep of override lists `jobs` for the job `job`, as Hydra types them."""
    swept = swept_keys(jobs)
    domains: dict[str, list[Any]] = {}
    for overrides in jobs:
        for key, value in _swept_values(overrides, swept).items():
            known = domains.setdefault(key, [])
            if value not in known:
                known.append(value)
    values = _swept_values(job, swept)
    return SweepAxes({key: domains[key] for key in values}, values)


def recorded_sweep_axes(sweep_dir: Path, job: Sequence[str]) -> SweepAxes:
    """`sweep_axes` of the sweep Hydra recorded in `sweep_dir` (none without a usable record)."""
    jobs = recorded_jobs(sweep_dir)
    return sweep_axes(jobs, job) if jobs else SweepAxes()


def _swept_values(overrides: Sequence[str], swept: set[str]) -> dict[str, Any]:
    chosen = [arg for arg in overrides if arg.partition("=")[0] in swept]
    return {override.key_or_group: override.value() for override in parse_overrides(chosen)}
