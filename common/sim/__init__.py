"""Simulation and data: the tracking gym, physics stepping, rewards, pushes, features, the buffer and the collector."""
