"""``laser-tracker bench real`` run on a few of its rows, for the tests of those rows."""
import argparse
import json
from pathlib import Path


def bench_real_row(tmp_path: Path, name: str, mode: str = 'motion', jobs: int = 1) -> dict:
    """The figures of one row of ``bench real`` in one mode (its work folder kept in
    ``tmp_path / 'work'``)."""
    from laser_tracker.tools import bench_real
    args = argparse.Namespace(only=[name], modes=[mode], config=[],
                              json=str(tmp_path / 'out.json'), markdown=False,
                              keep=str(tmp_path / 'work'), jobs=jobs)
    assert bench_real.run(args) == 0
    return json.loads((tmp_path / 'out.json').read_text())[name][mode]
