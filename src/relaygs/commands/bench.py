"""`python -m relaygs.bench splat|train|field|hull|sweeps [--json PATH]`: benchmarks, not tests."""

from __future__ import annotations

import argparse
import json

from relaygs.cli import OneLineErrorParser, one_line_failures, writable_file
from relaygs.commands import bench_field, bench_hull, bench_splat, bench_sweeps, bench_train

SUBCOMMANDS = {
    "splat": bench_splat,
    "train": bench_train,
    "sweeps": bench_sweeps,
    "field": bench_field,
    "hull": bench_hull,
}
"""Each subcommand's module: HELP, `add_arguments`, `measure` (None: failed) and `print_report`."""


def main(argv: list[str] | None = None) -> int:
    """Measure, print the table and write the JSON report; 2 on bad input, 1 on a failure."""
    parser = OneLineErrorParser(prog="python -m relaygs.bench", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module in SUBCOMMANDS.items():
        command = sub.add_parser(name, help=module.HELP)
        module.add_arguments(command)
        command.add_argument(
            "--json", type=writable_file, help="also write the results as JSON here"
        )
        command.set_defaults(measure=module.measure, print_report=module.print_report)
    args = parser.parse_args(argv)
    return one_line_failures(lambda: _measure_and_report(args), bad_input_exit=2)


def _measure_and_report(args: argparse.Namespace) -> int:
    """Measure, print the table and write the JSON report (1 when the measure failed)."""
    report = args.measure(args)
    if report is None:
        return 1
    args.print_report(report)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
    return 0
