"""A sweep's quality over time: test PSNR and fg-PSNR at every evaluated frame, one line per
variant (the mean over its seeds), from the jobs' `per_view.csv`: where each variant loses."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
from matplotlib.figure import Figure

from relaygs.app.figures import save_png
from relaygs.app.result import STATUS_OK
from relaygs.per_view import PER_VIEW_FILE, frame_means, means_by_key, read_per_view

FRAME_METRICS = (("psnr", "PSNR (dB)"), ("fg_psnr", "fg-PSNR (dB)"))  # a panel each
Curves = dict[str, dict[str, dict[int, float]]]  # {metric: {line label: {frame: value}}}


def frame_curves(table: pd.DataFrame) -> Curves:
    """Per metric and line (`line_labels`), the mean of its finished jobs' `per_view.csv`."""
    per_metric: dict[str, dict[str, list[dict[int, float]]]] = {}
    for label, (_, row) in zip(line_labels(table), table.iterrows(), strict=True):
        path = Path(str(row.get("run_dir"))) / PER_VIEW_FILE
        if row.get("status") != STATUS_OK or not path.is_file():
            continue
        records = read_per_view(path)
        for metric, _ in FRAME_METRICS:
            means = frame_means(records, metric)
            if means:
                per_metric.setdefault(metric, {}).setdefault(label, []).append(means)
    return {
        metric: {
            label: means_by_key(pair for job in jobs for pair in job.items())
            for label, jobs in per_label.items()
        }
        for metric, per_label in per_metric.items()
    }


def line_labels(table: pd.DataFrame) -> list[str]:
    """Each row's line: its variant, then the scene and dotted parameters that differ between
    rows of that variant (`relaygs (relay.k=8)`), so only repeats such as seeds share one."""
    candidates = [c for c in table.columns if c == "scene" or "." in c]
    labels = []
    for _, row in table.iterrows():
        same = table[table["variant"] == row["variant"]]
        varying = [c for c in candidates if same[c].astype(str).nunique() > 1]
        details = ", ".join(f"{column}={_text(row[column])}" for column in varying)
        labels.append(f"{row['variant']} ({details})" if details else str(row["variant"]))
    return labels


def plot_frame_curves(curves: Curves, path: Path, title: str) -> Path | None:
    """Write the curves to `path` (PNG), a panel per metric, a colour per line; None if none."""
    panels = [(label, curves[metric]) for metric, label in FRAME_METRICS if metric in curves]
    if not panels:
        return None
    names = list(dict.fromkeys(name for _, lines in panels for name in lines))
    colours = {name: f"C{index % 10}" for index, name in enumerate(names)}
    figure = Figure(figsize=(7.0, 3.2 * len(panels)), layout="constrained")
    axes_list = figure.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for axes, (label, lines) in zip(axes_list, panels, strict=True):
        for name, values in lines.items():
            axes.plot(
                list(values), list(values.values()), marker=".", color=colours[name], label=name
            )
        axes.set_ylabel(label)
        axes.grid(True, alpha=0.3)
        axes.legend(fontsize=8, loc="best")
    axes_list[0].set_title(f"{title}: test views by frame")
    axes_list[-1].set_xlabel("frame")
    return save_png(figure, path)


def _text(value: Any) -> str:
    """A label value, a whole float as an int (a column of ints with gaps holds floats)."""
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)
