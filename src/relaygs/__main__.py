"""`python -m relaygs`: the list of the relaygs commands (the package itself runs nothing)."""

import sys
from collections.abc import Sequence

COMMANDS = (
    ("run", "train and evaluate RelayGS, its ablations or 4D-GS; sweeps (+experiment=NAME)"),
    ("report", "rebuild a sweep's summary tables and Pareto plot from its result.json files"),
    ("artifacts", "inspect, score, render, export, verify and clean the artifact store"),
    ("synth", "write a synthetic multi-view video scene"),
    ("frames", "turn one video per camera into a multi-view scene's frame folders"),
    ("bench", "splatting, training-step and sweep benchmarks"),
)


def usage() -> str:
    """One line per command: how to start it and what it does."""
    width = max(len(name) for name, _ in COMMANDS)
    lines = ["relaygs commands (each takes --help):"]
    lines += [f"  python -m relaygs.{name:<{width}}  {what}" for name, what in COMMANDS]
    return "\n".join(lines)


def main(argv: Sequence[str]) -> int:
    """Print the list (exit 0); any argument but --help is a usage error (exit 2, one line), so
    that `python -m relaygs run ...` does not end in success having run nothing."""
    if list(argv) in ([], ["-h"], ["--help"]):
        print(usage())
        return 0
    name = argv[0]
    start = f"python -m relaygs.{name}" if name in dict(COMMANDS) else "python -m relaygs.NAME"
    print(
        f"error: python -m relaygs only lists the commands, got {' '.join(argv)!r}: "
        f"start one as `{start} ...` (see python -m relaygs)",
        file=sys.stderr,
    )
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
