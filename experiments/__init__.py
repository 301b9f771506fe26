"""Experiment configs, sweeps, the leaderboard and the ``sixaxis`` command line."""
