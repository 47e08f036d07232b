"""``laser-tracker config``: write or check the package's ROS parameter file.

``--write PATH`` renders the defaults of every node's parameters (``laser_tracker.parameters``)
as a ROS 2 parameter file: ``sick_lms_driver``, ``ego_motion`` (plus section ``ego_motion``),
``detection`` (grid, difference, blobs), ``tracking`` (hypotheses, kalman), ``active_head``
(plus section ``head``); algorithm parameters are ``<section>.<field>``.
``config/laser_tracker.yaml`` is this output, committed (a test keeps it equal to the
defaults, so every value is declared once, in the code).

``--check PATH`` loads a file as the nodes and ``replay`` would and reports the first problem
(unknown parameter, wrong type, value out of range) with exit status 2.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from laser_tracker import parameters
from laser_tracker.config import ConfigError, read_ros_yaml, render_ros_yaml
from laser_tracker.core.pipeline import PipelineConfig
from laser_tracker.io.atomic import atomic_path

HEADER = """\
# laser_tracker parameters, every node (ROS 2 parameter file).
# Generated from the code's defaults by `laser-tracker config --write config/laser_tracker.yaml`;
# the defaults are declared once, in the code (laser_tracker/parameters.py). Use it with
#   ros2 run laser_tracker <node> --ros-args --params-file config/laser_tracker.yaml
#   laser-tracker replay BAG --config config/laser_tracker.yaml
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument('--write', metavar='PATH',
                       help="write the defaults as a ROS parameter file ('-' = stdout)")
    group.add_argument('--check', metavar='PATH', help='validate a ROS parameter file')


def render_defaults() -> str:
    """The parameter file text of every node's defaults: nodes, sections and fields in
    declaration order. Descriptions and ranges are in the code and reach users through
    ``ros2 param describe``."""
    return render_ros_yaml(parameters.defaults(), HEADER)


def check(path: str | Path) -> PipelineConfig:
    """Load ``path`` as the nodes and replay would; ConfigError names the problem."""
    nodes = read_ros_yaml(path)
    if not any(n in nodes for n in parameters.NODE_SECTIONS):
        raise ConfigError(f'{path}: none of the nodes {", ".join(parameters.NODE_SECTIONS)} '
                          f'is configured')
    parameters.load(nodes, str(path))
    return PipelineConfig.from_ros_params(nodes, str(path))


def run(args: argparse.Namespace) -> int:
    if args.write:
        text = render_defaults()
        if args.write == '-':
            print(text, end='')
            return 0
        with atomic_path(Path(args.write), overwrite=True) as tmp:
            tmp.write_text(text)
        print(f'wrote {args.write}')
        return 0
    check(args.check)
    changed = _differences(read_ros_yaml(args.check))
    print(f'{args.check}: valid' + (f'; differs from the defaults in {len(changed)} '
                                     f'parameter(s):' if changed else '; all defaults'))
    for line in changed:
        print(f'  {line}')
    return 0


def _differences(nodes) -> list[str]:
    default = parameters.defaults()
    out = []
    for node, params in nodes.items():
        for name, value in params.items():
            if node in default and default[node].get(name) != value:
                out.append(f'{node}: {name} = {value!r} (default {default[node].get(name)!r})')
    return out
