"""`python -m relaygs.frames`: the command's entry point. It imports relaygs.commands.frames
only once started, so that a Ctrl-C while torch loads ends in one line (see `start_tool`)."""

from relaygs.cli import start_tool

if __name__ == "__main__":
    start_tool("relaygs.commands.frames")
