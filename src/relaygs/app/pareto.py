"""The accuracy-against-cost plot of a sweep: PSNR over training time, every job labelled,
the Pareto front (no other job is both faster and more accurate) marked."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Annotation
from matplotlib.transforms import Bbox

from relaygs.app.figures import save_png

LOG_SCALE_RATIO = 20.0
"""Use a log time axis when the slowest job takes more than this many times the fastest."""
LABEL_STEP_PT = 9.0
"""How far (points) a label that would overprint another is lifted at a time."""
MAX_LABEL_STEPS = 12
"""At most this many lifts per label: past them a label in a crowd of jobs may overprint."""


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
    notes = [
        axes.annotate(label, (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
        for (x, y), label in point_labels(times, scores, labels).items()
    ]
    positive = [t for t in times if t > 0]
    if positive and max(positive) > LOG_SCALE_RATIO * min(positive):
        axes.set_xscale("log")
    axes.set_xlabel("training time (s, whole lineage)")
    axes.set_ylabel("PSNR (dB)")
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best")
    spread_labels(figure, notes)
    return save_png(figure, path)


def spread_labels(figure: Figure, notes: Sequence[Annotation]) -> None:
    """Put labels that would run off the plot's right edge on their point's left, then lift
    them, lowest point first, in LABEL_STEP_PT steps (at most MAX_LABEL_STEPS) until each clears
    the labels placed before it: a few jobs close together (e.g. variants of one cost) stay
    readable."""
    renderer = FigureCanvasAgg(figure).get_renderer()
    figure.draw_without_rendering()  # the constrained layout places the axes first
    placed: list[Bbox] = []
    for note in sorted(notes, key=lambda each: each.xy[1]):
        right_edge = note.axes.get_window_extent(renderer).x1
        if note.get_window_extent(renderer).x1 > right_edge:  # to the point's left instead
            note.set_horizontalalignment("right")
            note.xyann = (-note.xyann[0], note.xyann[1])
        for _ in range(MAX_LABEL_STEPS):
            box = note.get_window_extent(renderer)
            if not any(box.overlaps(other) for other in placed):
                break
            x, y = note.xyann
            note.xyann = (x, y + LABEL_STEP_PT)
        placed.append(note.get_window_extent(renderer))
