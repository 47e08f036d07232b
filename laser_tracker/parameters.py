"""Every node's parameters, declared once: node name -> {section prefix: dataclass}.

The algorithm sections come from ``core.pipeline.NODES``; the node shells add their own
plain-named sections (prefix ''). ``config/laser_tracker.yaml`` is :func:`defaults` rendered
(``laser-tracker config --write``); :func:`load` validates a parameter file for every node.
Pure Python (no rclpy), so offline tools and tests use it too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from laser_tracker.config import ConfigError, from_dict, param, to_dict
from laser_tracker.core.head import HeadConfig
from laser_tracker.core.pipeline import NODES as PIPELINE_NODES
from laser_tracker.core.pipeline import PipelineConfig
from laser_tracker.sick.config import SickLmsConfig


@dataclass(frozen=True)
class EgoMotionNodeConfig:
    odom_frame: str = param('odom', 'Frame of the published poses (the odometry frame).')
    odom_wait: float = param(
        1.0, 'A scan waits up to this long (s) for odometry stamped at or after it, so the '
        'odometry prior is interpolated, not extrapolated (0: never wait).', min=0.0,
        max=10.0)


@dataclass(frozen=True)
class ActiveHeadNodeConfig:
    pan_joint: str = param('head_pan_joint', 'Name of the pan joint in head/command.')
    tilt_joint: str = param('head_tilt_joint', 'Name of the tilt joint in head/command.')
    max_pose_age: float = param(1.0, 'Tracks are aimed at only if the latest ego-motion pose '
                                     'is at most this old (s) relative to them.', min=0.0,
                                max=60.0)


def _node_sections() -> dict[str, dict[str, type]]:
    pipeline = PipelineConfig.section_types()
    nodes: dict[str, dict[str, type]] = {'sick_lms_driver': {'': SickLmsConfig}}
    for node, sections in PIPELINE_NODES.items():
        nodes[node] = {s: pipeline[s] for s in sections}
    nodes['ego_motion'] = {'': EgoMotionNodeConfig, **nodes['ego_motion']}
    nodes['active_head'] = {'': ActiveHeadNodeConfig, 'head': HeadConfig}
    return nodes


NODE_SECTIONS = _node_sections()


#: The paper's method alone (the reference mode): every measured addition that is not in the
#: paper switched off. ``laser-tracker config --write PATH --paper`` renders it.
PAPER_REFERENCE: dict[str, dict[str, Any]] = {
    'ego_motion': {                        # each scan matched against the previous scan
        'ego_motion.map_scans': 1,
        'ego_motion.map_min_translation': 0.0,
        'ego_motion.map_min_rotation': 0.0,
        'ego_motion.adaptive_prior': False,     # the configured odometry noise, fixed
        'ego_motion.prior_max_ratio': 0.0,
        'ego_motion.prior_gate': 0.0,
        'ego_motion.speed_check_jitter': 0.0,
    },
    'detection': {
        'grid.free_erosion': 0,            # free space only from each beam itself
        'difference.memory': 0,            # Eq. 1 against the previous grid alone
        'difference.motion_depth': 0.0,    # no platform-motion depth test
        'difference.pose_gate': False,     # every scan reports, whatever its ego-motion quality
        'blobs.position': 'changed',       # the blob is its changed cells
        'blobs.centre_offset': 0.0,
    },
}


def defaults(paper: bool = False) -> dict[str, dict[str, Any]]:
    """``{node: {dotted name: default}}`` for every node; ``paper``: the reference mode."""
    out: dict[str, dict[str, Any]] = {}
    for node, sections in NODE_SECTIONS.items():
        params: dict[str, Any] = {}
        for prefix, cls in sections.items():
            for key, value in to_dict(cls()).items():
                params[f'{prefix}.{key}' if prefix else key] = value
        if paper:
            unknown = set(PAPER_REFERENCE.get(node, {})) - set(params)
            assert not unknown, f'PAPER_REFERENCE names unknown parameters {unknown}'
            params.update(PAPER_REFERENCE.get(node, {}))
        out[node] = params
    return out


def load(nodes: dict[str, dict[str, Any]], source: str = '') -> dict[str, dict[str, Any]]:
    """Validate ``{node: {dotted: value}}`` (``config.read_ros_yaml``) for our nodes.

    Returns ``{node: {prefix: section instance}}``; nodes that are not ours are ignored
    (the file may configure other packages). ConfigError names the first problem.
    """
    where = f'{source}: ' if source else ''
    out: dict[str, dict[str, Any]] = {}
    for node, sections in NODE_SECTIONS.items():
        values: dict[str, dict[str, Any]] = {prefix: {} for prefix in sections}
        for name, value in (nodes.get(node) or {}).items():
            prefix, _, key = name.rpartition('.')
            if prefix not in sections:
                raise ConfigError(f'{where}node {node}: unknown parameter {name!r}')
            values[prefix][key] = value
        try:
            out[node] = {p: from_dict(sections[p], v, p) for p, v in values.items()}
        except ConfigError as exc:
            raise ConfigError(f'{where}node {node}: {exc}') from None
    return out
