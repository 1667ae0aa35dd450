"""Command-line entry points: ``swarmd`` (the daemon) and ``swarmctl`` (the operator tool)."""
