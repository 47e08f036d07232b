"""``laser-tracker config``: write or check the pipeline's ROS parameter file.

``--write PATH`` renders the defaults of every section (``core.pipeline.PipelineConfig``) as a
ROS 2 parameter file: node ``ego_motion``, node ``detection`` (grid, difference, blobs), node
``tracking`` (hypotheses, kalman), each parameter ``<section>.<field>``.
``config/laser_tracker.yaml`` is this output, committed (a test keeps it equal to the
defaults, so every value is declared once, in the code).

``--check PATH`` loads a file as the nodes and ``replay`` would and reports the first problem
(unknown parameter, wrong type, value out of range) with exit status 2.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from laser_tracker.config import ConfigError, read_ros_yaml, render_ros_yaml
from laser_tracker.core.pipeline import NODES, PipelineConfig
from laser_tracker.io.atomic import atomic_path

HEADER = """\
# laser_tracker pipeline parameters (ROS 2 parameter file).
# Generated from the code's defaults by `laser-tracker config --write config/laser_tracker.yaml`;
# the defaults are declared once, in laser_tracker/core/*.py. Use it with
#   ros2 run laser_tracker <node> --ros-args --params-file config/laser_tracker.yaml
#   laser-tracker replay BAG --config config/laser_tracker.yaml
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument('--write', metavar='PATH',
                       help="write the defaults as a ROS parameter file ('-' = stdout)")
    group.add_argument('--check', metavar='PATH', help='validate a ROS parameter file')


def render_defaults(config: PipelineConfig | None = None) -> str:
    """The parameter file text of ``config`` (default: the defaults), rendered with
    ``config.render_ros_yaml``: nodes, sections and fields in declaration order. Descriptions
    and ranges are in the code and reach users through ``ros2 param describe``."""
    return render_ros_yaml((config or PipelineConfig()).to_ros_params(), HEADER)


def check(path: str | Path) -> PipelineConfig:
    """Load ``path`` as the pipeline would; ConfigError names the problem."""
    nodes = read_ros_yaml(path)
    ours = [n for n in NODES if n in nodes]
    if not ours:
        raise ConfigError(f'{path}: none of the nodes {", ".join(NODES)} is configured')
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
    config = check(args.check)
    changed = _differences(config)
    print(f'{args.check}: valid' + (f'; differs from the defaults in {len(changed)} '
                                     f'parameter(s):' if changed else '; all defaults'))
    for line in changed:
        print(f'  {line}')
    return 0


def _differences(config: PipelineConfig) -> list[str]:
    default = PipelineConfig().to_ros_params()
    out = []
    for node, params in config.to_ros_params().items():
        for name, value in params.items():
            if default[node].get(name) != value:
                out.append(f'{node}: {name} = {value!r} (default {default[node].get(name)!r})')
    return out
