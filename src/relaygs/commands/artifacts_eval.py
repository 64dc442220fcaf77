"""`artifacts eval KEY --scene DIR [--lineage]`: score a stored model (and its lineage) on the
test views; `gap KEY`: its lineage on the train and test views, all, fg and bg pixels apart."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any

from relaygs.commands.artifact_models import (
    KEY_COLUMN_WIDTH,
    load_run_scene,
    model_artifact,
    note_other_scene,
)
from relaygs.data import Scene
from relaygs.device import set_threads, usable_device
from relaygs.per_view import PER_VIEW, write_per_view
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.store import ArtifactStore, MissingArtifactError, StoredArtifact
from relaygs.stages import evaluate
from relaygs.train.error_split import SPLIT_METRICS, error_split

LINEAGE_COLUMNS = ("psnr", "ssim", "fg_psnr", "num_gaussians", "storage_mb")
SPLITS = ("train", "test")


def run_eval(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Render the artifact's model (with `--lineage`, each model of its lineage too) at the
    scene's test views and print the test metrics, e.g. to see what each stage contributes."""
    device = usable_device(args.device, "--device")
    set_threads(args.threads)
    item, artifact = model_artifact(store, args.key)
    scene = load_run_scene(args, item)
    settings = {"eval": {"frame_stride": args.frame_stride}, "train": {"device": str(device)}}
    tests = ", ".join(str(camera.camera_id) for camera in scene.test_cameras) or "none"
    where = f"on {args.scene} (test cameras {tests})"
    if args.lineage:
        entries = lineage_entries(store, item)
        models = [store.load(entry.stage, entry.key) for entry in entries]  # damaged: before output
        print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]} and its lineage {where}")
        rows = []
        for entry, model in zip(entries, models, strict=True):
            scores = _scores(entry, model, scene, settings)
            cells = [cell(scores.get(name)) for name in LINEAGE_COLUMNS]
            rows.append([entry.stage, entry.key[:KEY_COLUMN_WIDTH], *cells])
        print(aligned_table(["stage", "key", *LINEAGE_COLUMNS], rows))
        note_other_scene(entries, scene)
        return 0
    metrics = _scores(item, artifact, scene, settings)
    print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]} {where}")
    for name, value in metrics.items():
        if isinstance(value, float | int) or value is None:
            print(f"  {name:<16}{cell(value)}")
    if args.per_view is not None:
        written = write_per_view(args.per_view, metrics[PER_VIEW])
        print(f"  per-view metrics of {len(metrics[PER_VIEW])} image(s) in {written}")
    note_other_scene([item], scene)
    return 0


def _scores(
    item: StoredArtifact, artifact: Artifact, scene: Scene, settings: Mapping[str, Any]
) -> dict[str, Any]:
    """The evaluator's metrics of one stored model, with its storage as result.json has it."""
    metrics = evaluate(scene, artifact, settings)
    metrics["storage_mb"] = item.manifest.size_mb
    return metrics


def lineage_entries(store: ArtifactStore, item: StoredArtifact) -> list[StoredArtifact]:
    """`item` and every artifact upstream of it, each once, upstream ones first."""
    ordered: dict[str, StoredArtifact] = {}

    def visit(entry: StoredArtifact) -> None:
        for parent in entry.manifest.lineage:
            if parent.key in ordered:
                continue
            if not store.has(parent.stage, parent.key):
                raise MissingArtifactError(
                    f"the lineage of {entry.stage} {entry.key[:KEY_COLUMN_WIDTH]} needs "
                    f"{parent.stage} {parent.key[:KEY_COLUMN_WIDTH]}, which is no longer in "
                    f"{store.root}: score the artifacts still there one by one"
                )
            manifest = store.manifest(parent.stage, parent.key)
            visit(StoredArtifact(store.path(parent.stage, parent.key), manifest))
        ordered[entry.key] = entry

    visit(item)
    return list(ordered.values())


def aligned_table(header: list[str], rows: list[list[str]]) -> str:
    """The header and rows as left-aligned, two-space-indented text columns."""
    lines = [header, *rows]
    widths = [max(len(line[column]) for line in lines) for column in range(len(header))]
    return "\n".join(
        "  "
        + "  ".join(text.ljust(width) for text, width in zip(line, widths, strict=True)).rstrip()
        for line in lines
    )


def cell(value: Any) -> str:
    """A metric as `eval` prints it: floats to 4 decimals, None as n/a."""
    if value is None:
        return "n/a"
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def run_gap(store: ArtifactStore, args: argparse.Namespace) -> int:
    """Print one row per model of the artifact's lineage (upstream first): SPLIT_METRICS on the
    train views and on the test views, and the train − test gap of the whole-image PSNR."""
    device = usable_device(args.device, "--device")
    set_threads(args.threads)
    item, _ = model_artifact(store, args.key)
    scene = load_run_scene(args, item)
    entries = lineage_entries(store, item)
    models = [store.load(entry.stage, entry.key) for entry in entries]  # damaged: before output
    header = ["stage", "key"]
    header += [f"{split}_{name}" for split in SPLITS for name in SPLIT_METRICS] + ["gap"]
    rows = []
    for entry, model in zip(entries, models, strict=True):
        scores = {
            split: error_split(scene, model, split, args.frame_stride, device, args.colour_fit)
            for split in SPLITS
        }
        cells = [cell(scores[split][name]) for split in SPLITS for name in SPLIT_METRICS]
        train, test = scores["train"]["psnr"], scores["test"]["psnr"]
        gap = None if train is None or test is None else train - test
        rows.append([entry.stage, entry.key[:KEY_COLUMN_WIDTH], *cells, cell(gap)])
    fitted = " (renders colour-fitted per camera)" if args.colour_fit else ""
    print(f"{item.stage} {item.key[:KEY_COLUMN_WIDTH]} and its lineage on {args.scene}{fitted}")
    print(aligned_table(header, rows))
    note_other_scene(entries, scene)
    return 0
