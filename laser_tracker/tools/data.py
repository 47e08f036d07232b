"""Where the public real recordings are (they are never part of the repository).

``real_data()`` is the folder given by the ``LASER_TRACKER_DATA`` environment variable, else
``shared/data`` beside the repository clone (the layout CI uses). README.md says where each
recording comes from. Tests and benchmarks that need a recording call :func:`real_recording`
and skip, or report, when it is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

ENV = 'LASER_TRACKER_DATA'
_REPO = Path(__file__).resolve().parents[2]


def real_data() -> Path:
    """The folder of the public real recordings (it may not exist)."""
    env = os.environ.get(ENV)
    return Path(env) if env else _REPO.parent / 'shared' / 'data'


def real_recording(relative: str) -> Path:
    """``real_data() / relative``, e.g. ``real_recording('carmen/mit-csail.clf')``."""
    return real_data() / relative
