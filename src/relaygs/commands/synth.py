"""`python -m relaygs.synth NAME OUT_DIR`: write a synthetic scene (Panoptic layout + scene.json);
bad input exits 2 with one line on stderr, a full disk or memory 1."""

from __future__ import annotations

import argparse
import time

from relaygs.cli import OneLineErrorParser, one_line_failures, path_argument
from relaygs.data.effects import ALL_EFFECTS
from relaygs.data.synthetic import PRESETS, generate


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the synth command."""
    parser = OneLineErrorParser(
        prog="python -m relaygs.synth",
        description="Render a synthetic multi-view video scene in the PanopticSports layout.",
        epilog="presets: "
        + "; ".join(f"{name}: {preset.description}" for name, preset in PRESETS.items()),
    )
    parser.add_argument("name", help=f"preset: {', '.join(PRESETS)}")
    parser.add_argument(
        "out_dir", type=path_argument, help="output folder (replaced if it holds a generated scene)"
    )
    parser.add_argument("--frames", type=int, default=64, help="number of frames T (default 64)")
    parser.add_argument("--width", type=int, default=160, help="image width (default 160)")
    parser.add_argument("--height", type=int, default=90, help="image height (default 90)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--effects",
        nargs="*",
        default=None,
        metavar="EFFECT",
        help="simulate exactly these effects instead of the preset's defaults "
        f"(space or comma separated; 'none' for no effects): {', '.join(sorted(ALL_EFFECTS))}",
    )
    return parser


def parse_effect_list(values: list[str] | None) -> list[str] | None:
    """Flatten space/comma separated effect names."""
    if values is None:
        return None
    return [name.strip() for value in values for name in value.split(",") if name.strip()]


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the process exit status."""
    args = build_parser().parse_args(argv)
    size = f"{args.width}x{args.height}"
    return one_line_failures(lambda: _generate(args), 2, f"rendering {size} images")


def _generate(args: argparse.Namespace) -> None:
    started = time.perf_counter()
    out = generate(
        args.name,
        args.out_dir,
        frames=args.frames,
        width=args.width,
        height=args.height,
        seed=args.seed,
        effects=parse_effect_list(args.effects),
        progress=True,
    )
    print(f"wrote {out} in {time.perf_counter() - started:.1f} s")
