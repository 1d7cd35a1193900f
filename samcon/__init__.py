"""SAMCON (Liu et al. 2010, 2015) and per-segment linear feedback (Liu et al. 2016): a sampling-based tracker.

It imports only :mod:`common`; no learner imports it. ``track-samcon`` (:mod:`samcon.track`) writes a run directory
that ``compare-trackers`` reads through :mod:`samcon.export`.
"""
