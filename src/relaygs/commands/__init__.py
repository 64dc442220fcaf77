"""The relaygs command-line tools: `relaygs/X.py` is the `python -m relaygs.X` entry point and
`relaygs/commands/X.py` the tool it starts (its `main`)."""
