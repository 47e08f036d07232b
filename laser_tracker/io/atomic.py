"""Outputs that appear whole or not at all (no half-written bag or folder after an error)."""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path


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
