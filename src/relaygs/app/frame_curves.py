"""A sweep's quality over time: test PSNR (and fg-PSNR, where the scene has masks) at every
evaluated frame, one line per variant (the mean over its jobs, e.g. seeds), read from the jobs'
`per_view.csv`. It shows where in the sequence, at which motion, each variant loses."""

from __future__ import annotations

import io
from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from relaygs.app.result import STATUS_OK
from relaygs.per_view import PER_VIEW_FILE, frame_means, read_per_view
from relaygs.pipeline.fsio import publish_bytes

FRAME_METRICS = (("psnr", "PSNR (dB)"), ("fg_psnr", "fg-PSNR (dB)"))
"""The metrics plotted, one panel each (a panel without values is left out)."""

Curves = dict[str, dict[int, float]]
"""{line label: {frame: value}}."""


def frame_curves(table: pd.DataFrame) -> dict[str, Curves]:
    """{metric: curves} for FRAME_METRICS: per label (the variant, with the scene when the
    sweep has several), the mean over its finished jobs of the metric at each frame. Jobs
    without a `per_view.csv` are left out, and so is a metric no job has."""
    several_scenes = "scene" in table and table["scene"].nunique() > 1
    per_metric: dict[str, dict[str, list[dict[int, float]]]] = {}
    for _, row in table.iterrows():
        path = Path(str(row.get("run_dir"))) / PER_VIEW_FILE
        if row.get("status") != STATUS_OK or not path.is_file():
            continue
        records = read_per_view(path)
        label = f"{row['variant']} ({row['scene']})" if several_scenes else str(row["variant"])
        for metric, _ in FRAME_METRICS:
            means = frame_means(records, metric)
            if means:
                per_metric.setdefault(metric, {}).setdefault(label, []).append(means)
    return {
        metric: {label: _mean_by_frame(jobs) for label, jobs in per_label.items()}
        for metric, per_label in per_metric.items()
    }


def plot_frame_curves(table: pd.DataFrame, path: Path, title: str) -> Path | None:
    """Write the per-frame plot to `path` (PNG); None, and nothing written, when no job has
    per-view metrics."""
    curves = frame_curves(table)
    panels = [(label, curves[metric]) for metric, label in FRAME_METRICS if metric in curves]
    if not panels:
        return None
    figure = Figure(figsize=(7.0, 3.2 * len(panels)), layout="constrained")
    axes_list = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for axes, (label, lines) in zip(axes_list, panels, strict=True):
        for name, values in lines.items():
            axes.plot(list(values), list(values.values()), marker=".", label=name)
        axes.set_ylabel(label)
        axes.grid(True, alpha=0.3)
    axes_list[0].set_title(f"{title}: test views by frame")
    axes_list[0].legend(fontsize=8, loc="best")
    axes_list[-1].set_xlabel("frame")
    image = io.BytesIO()
    figure.savefig(image, format="png", dpi=120)
    publish_bytes(Path(path), image.getvalue())  # whole: a concurrent report never leaves half
    return Path(path)


def _mean_by_frame(jobs: list[dict[int, float]]) -> dict[int, float]:
    """Per frame, the mean over the jobs that evaluated it, frames in order."""
    frames = sorted({frame for job in jobs for frame in job})
    return {
        frame: sum(job[frame] for job in jobs if frame in job) / sum(frame in job for job in jobs)
        for frame in frames
    }
