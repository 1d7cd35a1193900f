"""The run directory: resolved config and run info, metrics logs, atomic checkpoints and exact resume."""
