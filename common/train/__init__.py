"""Training and judging: the training loop, run directories, checkpoints, logs, configs, the evaluator and renderer."""
