"""Outputs that appear whole or not at all (no half-written bag or folder after an error)."""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np


@contextlib.contextmanager
def atomic_path(target: str | Path, overwrite: bool = False):
    """Yield a temporary sibling path; on success move it to ``target``, on error remove it.

    Works for a file or a folder (a rosbag2 recording is a folder) written at the yielded path.
    """
    target = Path(target)
    if target.exists() and not overwrite:
        raise FileExistsError(f'{target}: already exists (remove it or choose another name)')
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
