"""`python -m relaygs.artifacts gap KEY --scene DIR`: each model of a lineage scored on the
views it trained on and on the held-out ones, over all, foreground and background pixels."""

from __future__ import annotations

import argparse

from relaygs.commands.artifact_models import (
    KEY_COLUMN_WIDTH,
    load_run_scene,
    model_artifact,
    note_other_scene,
)
from relaygs.commands.artifacts_eval import aligned_table, cell, lineage_entries
from relaygs.device import set_threads, usable_device
from relaygs.pipeline.store import ArtifactStore
from relaygs.train.error_split import SPLIT_METRICS, error_split

SPLITS = ("train", "test")


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
    note_other_scene(entries, scene, args)
    return 0
