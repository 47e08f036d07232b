"""Outputs that appear whole or not at all (no half-written bag or folder after an error)."""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from laser_tracker.errors import LaserTrackerError


class OutputPathError(LaserTrackerError):
    """An output that cannot be written where asked (exists, not a folder, not writable)."""


def check_output(target: str | Path, overwrite: bool = False) -> Path:
    """Check, before any work, that ``target`` (a file or folder to write) can be written:
    it does not exist unless ``overwrite``, and the folder it goes in is (or can be made
    in) a writable folder. OutputPathError names the problem and the fix; returns ``target``.
    """
    target = Path(target)
    if target.exists() and not overwrite:
        raise OutputPathError(f'{target}: already exists (use --overwrite to replace it, or '
                              'choose another name)')
    parent = target.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputPathError(f'{target}: cannot be written: {parent} is not a folder')
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputPathError(f'{target}: cannot be written: no permission to write in '
                              f'{parent}')
    return target


@contextlib.contextmanager
def removed_on_failure(folder: str | Path):
    """Around the work that fills ``folder``: if the folder did not exist before and the work
    fails or is interrupted, remove it, so no empty or partial output is left behind."""
    folder = Path(folder)
    existed = folder.exists()
    try:
        yield folder
    except BaseException:
        if not existed:
            shutil.rmtree(folder, ignore_errors=True)
        raise


@contextlib.contextmanager
def atomic_path(target: str | Path, overwrite: bool = False):
    """Yield a temporary sibling path; on success move it to ``target``, on error remove it.

    Works for a file or a folder (a rosbag2 recording is a folder) written at the yielded path.
    """
    target = check_output(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp_root = Path(tempfile.mkdtemp(prefix=f'.{target.name}.', dir=target.parent))
    tmp = tmp_root / target.name
    try:
        yield tmp
        if target.exists():
            shutil.rmtree(target) if target.is_dir() else target.unlink()
        os.replace(tmp, target)
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as indented JSON, atomically; numpy scalars and arrays become numbers
    and lists."""
    path = Path(path)
    with atomic_path(path, overwrite=True) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, default=_json_default) + '\n')
    return path


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f'{type(o).__name__} is not JSON serialisable')
