"""Mean ± std over seeds: one row per group of a sweep's jobs that differ only in their seed;
Δ PSNR is averaged from each seed's own (so seed-to-seed scene difficulty cancels out)."""

from __future__ import annotations

import statistics

import pandas as pd

from relaygs.app.result import STATUS_FAILED
from relaygs.app.summary import is_number, markdown_cell

METRICS = (
    ("PSNR ↑", "psnr", 2),
    ("Δ PSNR", "delta_psnr", 2),
    ("PSNR cf ↑", "psnr_cf", 2),
    ("fg-PSNR ↑", "fg_psnr", 2),
    ("SSIM ↑", "ssim", 4),
    ("Train (s)", "train_s_total", 1),
    ("Storage (MB)", "storage_mb", 2),
    ("FPS", "render_fps", 1),
    ("Gaussians", "num_gaussians", 0),
)


LABELS = {"scene": "Scene", "variant": "Variant", "test_set": "Test set"}  # else the key


def aggregate_table(summary: pd.DataFrame) -> pd.DataFrame:
    """One row per group of finished jobs that differ only in their seed (scene, variant, the
    parameters within a variant, `test_set`), in order of first appearance, with `runs`,
    `seeds` and each METRICS column's `_mean` and `_std` (sample std, None for one run)."""
    table = summary
    if "status" in table:
        table = table[table["status"] != STATUS_FAILED]
    parameters = _within_variant_parameters(table)
    keys = ["scene", "variant", *parameters, *(["test_set"] if "test_set" in table else [])]
    rows = []
    for values, group in table.groupby(keys, sort=False, dropna=False):
        row: dict[str, object] = {**dict(zip(keys, values, strict=True)), "runs": len(group)}
        row["seeds"] = group["seed"].nunique() if "seed" in group else len(group)
        for _, column, _ in METRICS:
            values = [float(v) for v in group.get(column, []) if is_number(v)]
            row[f"{column}_mean"] = statistics.fmean(values) if values else None
            row[f"{column}_std"] = statistics.stdev(values) if len(values) > 1 else None
        rows.append(row)
    return pd.DataFrame(rows)


def _within_variant_parameters(table: pd.DataFrame) -> list[str]:
    """The dotted keys that take more than one value among the jobs of one scene and variant."""
    groups = table.groupby(["scene", "variant"], sort=False, dropna=False)
    return [
        column
        for column in table.columns
        if "." in column and (groups[column].nunique(dropna=False) > 1).any()
    ]


def aggregate_markdown(table: pd.DataFrame, title: str) -> str:
    """The aggregate as a Markdown table of `mean ± std` after the columns that tell rows apart."""
    keys = list(table.columns[: list(table.columns).index("runs")])
    names = [key for key in keys if key != "test_set"]
    if "test_set" in keys and table.duplicated(names).any():
        names.append("test_set")
    labels = [LABELS.get(name, name) for name in names]
    header = "| " + " | ".join([*labels, "Runs"] + [label for label, _, _ in METRICS]) + " |"
    rule = "|" + ":---|" * len(names) + "---:|" + "---:|" * len(METRICS)
    lines = [f"# {title}", "", header, rule]
    for _, row in table.convert_dtypes().iterrows():
        cells = [markdown_cell(row[name], "{}") for name in names] + [str(row["runs"])]
        for _, column, digits in METRICS:
            cells.append(_mean_std(row[f"{column}_mean"], row[f"{column}_std"], digits))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _mean_std(mean: object, std: object, digits: int) -> str:
    """`mean ± std` with `digits` decimals (the mean alone without a std), or MISSING."""
    spec = f"{{:.{digits}f}}"
    text = markdown_cell(mean, spec)
    return f"{text} ± {markdown_cell(std, spec)}" if is_number(mean) and is_number(std) else text
