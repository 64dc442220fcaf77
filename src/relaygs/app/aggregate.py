"""Mean ± std over seeds: one row per (scene, variant) of a sweep that repeats jobs over seeds,
and per test set where runs of a pair were scored on different images (other downscales).

Δ PSNR is computed per seed against the reference variant on the same scene and seed (the
summary's `delta_psnr`), then averaged, so seed-to-seed scene difficulty cancels out.
"""

from __future__ import annotations

import math

import pandas as pd

from relaygs.app.result import STATUS_FAILED
from relaygs.app.summary import MISSING, is_number

METRICS = (
    ("PSNR ↑", "psnr", 2),
    ("Δ PSNR", "delta_psnr", 2),
    ("fg-PSNR ↑", "fg_psnr", 2),
    ("SSIM ↑", "ssim", 4),
    ("Train (s)", "train_s_total", 0),
    ("Storage (MB)", "storage_mb", 2),
    ("FPS", "render_fps", 1),
    ("Gaussians", "num_gaussians", 0),
)


def aggregate_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Per (scene, variant) and, where results record it, `test_set` (PSNR on other images
    does not average), in order of first appearance: `runs` (finished jobs), and
    `<metric>_mean` / `<metric>_std` (sample std, 0 for one run) of every METRICS column."""
    table = summary
    if "status" in table:
        table = table[table["status"] != STATUS_FAILED]
    keys = ["scene", "variant", *(["test_set"] if "test_set" in table else [])]
    rows = []
    for values, group in table.groupby(keys, sort=False, dropna=False):
        row: dict[str, object] = {**dict(zip(keys, values, strict=True)), "runs": len(group)}
        for _, column, _ in METRICS:
            values = [float(v) for v in group.get(column, []) if is_number(v)]
            row[f"{column}_mean"] = sum(values) / len(values) if values else None
            row[f"{column}_std"] = _std(values) if values else None
        rows.append(row)
    return pd.DataFrame(rows)


def aggregate_markdown(table: pd.DataFrame, title: str) -> str:
    """The aggregate as a Markdown table, each metric as `mean ± std`; with a `Test set`
    column where a (scene, variant) pair has rows on different images."""
    split = "test_set" in table and table.duplicated(["scene", "variant"]).any()
    names = ["scene", "variant", *(["test_set"] if split else [])]
    labels = ["Scene", "Variant", *(["Test set"] if split else []), "Runs"]
    header = "| " + " | ".join(labels + [label for label, _, _ in METRICS]) + " |"
    rule = "|" + ":---|" * len(names) + "---:|" + "---:|" * len(METRICS)
    lines = [f"# {title}", "", header, rule]
    for _, row in table.iterrows():
        cells = [str(row[name]) for name in names] + [str(row["runs"])]
        for _, column, digits in METRICS:
            cells.append(_mean_std(row[f"{column}_mean"], row[f"{column}_std"], digits))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _std(values: list[float]) -> float:
    """Sample standard deviation (0 for a single value)."""
    if len(values) < 2:
        return 0.0
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


def _mean_std(mean: object, std: object, digits: int) -> str:
    """`mean ± std` with `digits` decimals, or MISSING."""
    if not is_number(mean):
        return MISSING
    std_value = float(std) if is_number(std) else 0.0
    return f"{float(mean):.{digits}f} ± {std_value:.{digits}f}"
