"""The shared evaluator (deterministic episodes from fixed starts) and the tracking metrics it reports."""
