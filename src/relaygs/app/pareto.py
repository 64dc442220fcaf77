"""The accuracy-against-cost plot of a sweep: PSNR over training time, every job labelled,
the Pareto front (no other job is both faster and more accurate) marked."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.figure import Figure

from relaygs.app.figures import save_png

LOG_SCALE_RATIO = 20.0
"""Use a log time axis when the slowest job takes more than this many times the fastest."""


def pareto_front(times: Sequence[float], scores: Sequence[float]) -> list[int]:
    """Indices of the points no other point beats (time ≤ and score ≥, one strictly),
    ordered by time."""
    order = sorted(range(len(times)), key=lambda i: (times[i], -scores[i]))
    front: list[int] = []
    best = -math.inf
    for index in order:
        if scores[index] > best:
            front.append(index)
            best = scores[index]
    return front


def point_labels(
    times: Sequence[float], scores: Sequence[float], labels: Sequence[str]
) -> dict[tuple[float, float], str]:
    """One label per distinct point: jobs that landed on the same point (e.g. a cached
    variant) share it as `a, b`, so their labels do not overprint."""
    merged: dict[tuple[float, float], list[str]] = {}
    for x, y, label in zip(times, scores, labels, strict=True):
        names = merged.setdefault((x, y), [])
        if label not in names:
            names.append(label)
    return {point: ", ".join(names) for point, names in merged.items()}


def plot_pareto(
    times: Sequence[float], scores: Sequence[float], labels: Sequence[str], path: Path, title: str
) -> Path:
    """Write the labelled scatter with its Pareto front as a step line to `path` (PNG)."""
    figure = Figure(figsize=(7.0, 4.5), layout="constrained")
    axes = figure.add_subplot()
    axes.scatter(times, scores, color="tab:blue", zorder=2, label="job")
    front = pareto_front(times, scores)
    if front:
        front_times, front_scores = [times[i] for i in front], [scores[i] for i in front]
        axes.step(
            front_times,
            front_scores,
            where="post",
            color="tab:red",
            zorder=1,
            label="Pareto front",
        )
        axes.scatter(
            front_times,
            front_scores,
            facecolors="none",
            edgecolors="tab:red",
            s=140,
            zorder=3,
        )
    for (x, y), label in point_labels(times, scores, labels).items():
        axes.annotate(label, (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    positive = [t for t in times if t > 0]
    if positive and max(positive) > LOG_SCALE_RATIO * min(positive):
        axes.set_xscale("log")
    axes.set_xlabel("training time (s, whole lineage)")
    axes.set_ylabel("PSNR (dB)")
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    axes.legend(loc="lower right")
    return save_png(figure, path)
