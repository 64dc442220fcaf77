"""`python -m relaygs`: the list of the relaygs commands (the package itself runs nothing)."""

import sys

COMMANDS = (
    ("run", "train and evaluate RelayGS, its ablations or 4D-GS; sweeps (+experiment=NAME)"),
    ("report", "rebuild a sweep's summary tables and Pareto plot from its result.json files"),
    ("artifacts", "inspect, score, render, verify and clean the artifact store"),
    ("synth", "write a synthetic multi-view video scene"),
    ("bench", "splatting, training-step and sweep benchmarks"),
)


def usage() -> str:
    """One line per command: how to start it and what it does."""
    width = max(len(name) for name, _ in COMMANDS)
    lines = ["relaygs commands (each takes --help):"]
    lines += [f"  python -m relaygs.{name:<{width}}  {what}" for name, what in COMMANDS]
    return "\n".join(lines)


if __name__ == "__main__":
    print(usage())
    sys.exit(0)
