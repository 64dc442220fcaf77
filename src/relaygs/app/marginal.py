"""What one more minute buys: over `budget.multiplier`, each pipeline's PSNR per budget, the
gain per extra minute over its next cheaper budget, and whether it is on the Pareto front."""

from __future__ import annotations

import pandas as pd

from relaygs.app.pareto import pareto_front
from relaygs.app.result import STATUS_FAILED
from relaygs.app.summary import MISSING, is_number

MULTIPLIER = "budget.multiplier"
SECONDS_PER_MINUTE = 60.0


def varies_budget(table: pd.DataFrame) -> bool:
    """Whether the sweep's jobs ran at two or more step multipliers."""
    return MULTIPLIER in table and table[MULTIPLIER].dropna().nunique() >= 2


def marginal_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Per scene, pipeline and multiplier: seeds averaged, dB per extra minute, on the front."""
    table = summary
    if "status" in table:
        table = table[table["status"] != STATUS_FAILED]
    times = table.train_s_total
    scored = [is_number(p) and is_number(t) for p, t in zip(table.psnr, times, strict=True)]
    table = table.loc[pd.Series(scored, index=table.index, dtype=bool)]
    if table.empty:  # every job failed or has no time: no point to draw
        return pd.DataFrame()
    points = (
        table.astype({"psnr": float, "train_s_total": float})
        .groupby(["scene", "pipeline", MULTIPLIER], sort=False)
        .agg(runs=("psnr", "size"), seconds=("train_s_total", "mean"), psnr=("psnr", "mean"))
        .reset_index()
    )
    points["minutes"] = points.seconds / SECONDS_PER_MINUTE
    rows = []
    for scene, jobs in points.groupby("scene", sort=False):
        front = {jobs.index[i] for i in pareto_front(list(jobs.minutes), list(jobs.psnr))}
        for pipeline, runs in jobs.groupby("pipeline", sort=False):
            previous = None
            for index, point in runs.sort_values(MULTIPLIER).iterrows():
                gain = None
                if previous is not None and point.minutes > previous.minutes:
                    gain = (point.psnr - previous.psnr) / (point.minutes - previous.minutes)
                rows.append(
                    {
                        "scene": scene,
                        "pipeline": pipeline,
                        "multiplier": float(point[MULTIPLIER]),
                        "runs": int(point.runs),
                        "minutes": float(point.minutes),
                        "psnr": float(point.psnr),
                        "db_per_minute": gain,
                        "on_front": index in front,
                    }
                )
                previous = point
    return pd.DataFrame(rows)


def marginal_markdown(table: pd.DataFrame, title: str) -> str:
    """The table as Markdown: one row per budget point, the gain as dB per extra minute."""
    lines = [
        f"# {title}",
        "",
        "| Scene | Pipeline | Steps x | Runs | Train (min) | PSNR ↑ | dB per extra min | Front |",
        "|:---|:---|---:|---:|---:|---:|---:|:---|",
    ]
    for _, row in table.iterrows():
        gain = f"{row.db_per_minute:+.3f}" if is_number(row.db_per_minute) else MISSING
        cells = [
            str(row.scene),
            str(row.pipeline),
            f"{row.multiplier:g}",
            str(row.runs),
            f"{row.minutes:.2f}",
            f"{row.psnr:.2f}",
            gain,
            "yes" if row.on_front else "no",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
