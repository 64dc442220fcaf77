"""A sweep's PSNR over training time, every job labelled and the Pareto front marked."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.figure import Figure
from matplotlib.text import Annotation, Text
from matplotlib.transforms import Bbox

from relaygs.app.figures import save_png

LOG_SCALE_RATIO = 20.0  # a log time axis when the slowest job takes more times the fastest
LABEL_STEP_PT = 9.0  # how far (points) a label that would overprint another moves at a time
LABEL_ROOM = 0.15  # vertical margin (of the data range) that leaves labels room in the axes
MAX_LABEL_STEPS = 12  # steps up or down per label at most: in a larger crowd labels overprint
LABEL_STEPS = [0, *(sign * step for step in range(1, MAX_LABEL_STEPS + 1) for sign in (1, -1))]


def pareto_front(times: Sequence[float], scores: Sequence[float]) -> list[int]:
    """Indices of the points no other beats (time ≤ and score ≥, one strictly), by time."""
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
    """One label per distinct point: jobs on the same point share it as `a, b`."""
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
        step = {"where": "post", "color": "tab:red", "zorder": 1, "label": "Pareto front"}
        axes.step(front_times, front_scores, **step)
        ring = {"facecolors": "none", "edgecolors": "tab:red", "s": 140, "zorder": 3}
        axes.scatter(front_times, front_scores, **ring)
    leader = {"arrowstyle": "-", "color": "0.6", "linewidth": 0.6, "shrinkA": 0, "shrinkB": 3}
    placement = {"textcoords": "offset points", "xytext": (5, 5), "fontsize": 8}
    notes = [  # each with a leader line to its point, for a label moved off it
        axes.annotate(label, point, arrowprops=leader, **placement)
        for point, label in point_labels(times, scores, labels).items()
    ]
    axes.margins(y=LABEL_ROOM)
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
    """Put labels that would leave the plot on their point's left, then move each, lowest first,
    by LABEL_STEP_PT to the nearest place inside the axes that clears the labels placed before."""
    renderer = FigureCanvasAgg(figure).get_renderer()
    figure.draw_without_rendering()  # the constrained layout places the axes first
    placed: list[Bbox] = []
    for note in sorted(notes, key=lambda each: each.xy[1]):
        inside = note.axes.get_window_extent(renderer)
        if _text_box(note, renderer).x1 > inside.x1:  # to the point's left instead
            note.set_horizontalalignment("right")
            note.xyann = (-note.xyann[0], note.xyann[1])
        x, y = note.xyann
        for step in LABEL_STEPS:
            note.xyann = (x, y + step * LABEL_STEP_PT)
            box = _text_box(note, renderer)
            fits = inside.y0 <= box.y0 and box.y1 <= inside.y1
            if fits and not any(box.overlaps(other) for other in placed):
                break
        else:
            note.xyann = (x, y)  # no free place near: where it started
        placed.append(_text_box(note, renderer))


def _text_box(note: Annotation, renderer: RendererAgg) -> Bbox:
    """Where a label's text is drawn (the annotation's own extent includes its leader line)."""
    return Text.get_window_extent(note, renderer)
