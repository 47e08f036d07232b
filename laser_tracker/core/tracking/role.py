"""The common ground of the tracker's roles."""
from __future__ import annotations


class Role:
    """A part of the tracker. It reads its parameters from ``config`` (the
    ``hypotheses.*`` section), updates hypotheses with the Kalman ``filter``
    (``kalman.TrackFilter``) where it needs to, and counts what it does in ``stats`` (shared
    by all roles). New parameters are given to every role by assigning ``config`` and
    ``filter``; what a role remembers between frames stays."""

    def __init__(self, config, filter, stats: dict):
        self.config, self.filter, self.stats = config, filter, stats
