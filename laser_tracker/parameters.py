"""Every node's parameters, declared once, and the one loader that reads them.

``NODE_SECTIONS``: node name -> {section prefix: dataclass}; the algorithm sections come from
``core.pipeline.NODES``, the node shells add their own plain-named section (prefix '').
``config/laser_tracker.yaml`` is :func:`defaults` rendered (``laser-tracker config --write``).

:func:`load` is the single configuration path: the nodes at start-up (with the parameter
files and ``-p`` overrides rclpy was given), ``laser-tracker replay --config`` and
``laser-tracker config --check`` all call it, so they accept and refuse the same things:

* entries are matched to nodes by ROS 2's rules (``tracking``, ``/tracking``,
  ``/robot1/tracking``, ``/**/tracking``, ``/**``; see ``config.ParameterEntry.matches``);
  offline, with no namespace given, the namespace part of a key matches any namespace;
* an entry that configures none of our nodes, or a parameter that no node it configures
  has, is an error; ``use_sim_time`` (built into every ROS node) is accepted everywhere;
* values are checked by ``config.check_value`` (an integer is a fine float; ranges; choices);
* every error is one line: ``FILE: node NODE: parameter NAME: problem``.

Pure Python (no rclpy), so offline tools and tests use it too.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from laser_tracker.config import (ConfigError, ParameterEntry, check_value, describe,
                                  from_dict, param, read_parameter_file, to_dict)
from laser_tracker.core.head import HeadConfig
from laser_tracker.core.pipeline import NODES as PIPELINE_NODES
from laser_tracker.core.pipeline import PipelineConfig
from laser_tracker.sick.config import SickLmsConfig

#: Parameters that every ROS node has (rclpy declares them itself): accepted for every node.
ROS_BUILTIN: dict[str, Any] = {'use_sim_time': False}
#: Parameter name prefixes that ROS itself interprets (none used by these nodes).
ROS_BUILTIN_PREFIXES: tuple[str, ...] = ()
COMMAND_LINE = 'command line'


@dataclass(frozen=True)
class EgoMotionNodeConfig:
    odom_frame: str = param('odom', 'Frame of the published poses (the odometry frame).')
    odom_wait: float = param(
        1.0, 'A scan waits up to this long (s) for odometry stamped at or after it, so the '
        'odometry prior is interpolated, not extrapolated (0: never wait). When odometry '
        'stops this is paid once; scans then flow on the motion model until it returns.',
        min=0.0, max=10.0)


@dataclass(frozen=True)
class DetectionNodeConfig:
    status_topic: str = param(
        'ego_motion/status', 'Topic of the ego-motion status (diagnostic_msgs/'
        'DiagnosticArray, one per pose) that tells detection whether each pose can be '
        "trusted; '' = trust every pose (another localisation publishes ego_motion).",
        read_only='subscriptions are made at start-up')


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
    nodes['detection'] = {'': DetectionNodeConfig, **nodes['detection']}
    nodes['active_head'] = {'': ActiveHeadNodeConfig, 'head': HeadConfig}
    return nodes


NODE_SECTIONS = _node_sections()
#: The nodes whose parameters shape what offline replay computes.
REPLAY_NODES = ('ego_motion', 'detection', 'tracking')


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
        'self_mask.learn': False,          # nothing of the robot's body is masked
        'self_mask.beam_width': 0.0,       # nor mixed returns at nearer edges
        'self_mask.noise_sigmas': 0.0,     # the tolerance alone
    },
    'detection': {
        'grid.free_erosion': 0,            # free space only from each beam itself
        'grid.no_return_bounds': False,    # a beam without a return frees no_return_free
        'difference.memory': 0,            # Eq. 1 against the previous grid alone
        'difference.motion_depth': 0.0,    # no platform-motion depth test
        'difference.footprint': False,     # free before = the beam nearest the cell's centre
        'difference.pose_gate': False,     # every scan reports, whatever its ego-motion quality
        'difference.free_window': 0.0,     # free before = free in the previous grid
        'difference.static_time': 0.0,     # no static background
        'difference.walked_out_window': 0.0,  # a person walked in, never out
        'difference.max_scan_rate': 0.0,   # every scan, however fast the scanner
        'difference.ignore_lone_returns': False,  # every return can be a change
        'blobs.position': 'changed',       # the blob is its changed cells
        'blobs.centre_offset': 0.0,
        'person_detector.enabled': False,  # what moves only: no people by leg shape
    },
    'tracking': {
        'hypotheses.creation_window': 0.0,  # creation pairs with the previous frame only
        'hypotheses.ride_along_speed': 0.0,  # no ride-along test
        'hypotheses.ride_along_reach': 0.0,
        'hypotheses.segment_gate': 0.0,    # a hypothesis without a blob coasts and fades
        'hypotheses.person_min_travel': 0.0,
        'hypotheses.view_travel_ratio': 0.0,  # no travel against the view's change
        'hypotheses.person_confirm_samples': 0,
        'hypotheses.person_confirm_pairs': 0,
        'hypotheses.person_confirm_time': 0.0,
        'hypotheses.resume_time': 0.0,     # a lost track's id is never resumed
        'hypotheses.resume_confirms': False,  # nor taken over by a new hypothesis
        'hypotheses.duplicate_radius': 0.0,  # every hypothesis confirms after 4 samples
        'hypotheses.confirm_min_travel': 0.0,
        'hypotheses.confirm_when_measured': False,  # confirmed on the m-th sample, as it comes
        'hypotheses.person_blob_gate': 0.0,  # every track takes blobs within the gate
        'hypotheses.new_when_ungated': False,  # Eq. 2 alone says which blob is new
        'hypotheses.confirm_time': 0.0,    # 4 samples, however short a time they span
        'hypotheses.person_initial_weight': 0.0,  # every hypothesis starts at initial_weight
        'hypotheses.seen_empty_radius': 0.0,  # every confirmed hypothesis is reported,
        'hypotheses.report_hidden': True,     # hidden or not
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


def field_of(node: str, name: str):
    """``(prefix, dataclasses.Field)`` of parameter ``name`` of ``node``, or None."""
    sections = NODE_SECTIONS[node]
    prefix, _, key = name.rpartition('.')
    cls = sections.get(prefix)
    if cls is None:
        return None
    return next(((prefix, f) for n, f in describe(cls) if n == key), None)


def near_parameters(name: str) -> str:
    """``; did you mean A (node), B (node)?`` for the parameters of our nodes whose names are
    close to ``name`` (difflib), or ''."""
    import difflib

    owners: dict[str, list[str]] = {}
    for node, sections in NODE_SECTIONS.items():
        for prefix, cls in sections.items():
            for key, _ in describe(cls):
                owners.setdefault(f'{prefix}.{key}' if prefix else key, []).append(node)
    near = difflib.get_close_matches(name, list(owners), n=3, cutoff=0.75)
    if not near:
        return ''
    return '; did you mean ' + ', '.join(f'{n} ({", ".join(owners[n])})' for n in near) + '?'


def entries_for_other_namespaces(entries: Iterable[ParameterEntry], node: str,
                                 namespace: str) -> list[ParameterEntry]:
    """The entries written for ``node`` by its name (not ``/**``) that do not apply to it in
    ``namespace`` while none of them does: ROS drops them without a word (``ego_motion:``
    is ``/ego_motion``, not ``/robot1/ego_motion``)."""
    named = [e for e in entries
             if e.matches(node, None) and e.key.rstrip('/').rpartition('/')[2] != '**']
    if any(e.matches(node, namespace) for e in named):
        return []
    return named


def other_namespace_warning(entry: ParameterEntry, node: str, namespace: str) -> str:
    """The one-line warning for an entry of :func:`entries_for_other_namespaces`."""
    fqn = namespace.rstrip('/') + '/' + node
    return (f'{entry.source}: entry {entry.key!r} does not configure this node, {fqn} (a key '
            f'without a namespace means the root namespace): its parameters are ignored; '
            f"write '/**/{node}:' (any namespace) or '{fqn}:'")


def is_builtin(name: str) -> bool:
    return name in ROS_BUILTIN or bool(ROS_BUILTIN_PREFIXES) and \
        name.startswith(ROS_BUILTIN_PREFIXES)


def check_parameter(node: str, name: str, value: Any, source: str = '') -> Any:
    """One value of one node, validated as everywhere; returns it coerced. ConfigError
    ``SOURCE: node NODE: parameter NAME: problem``."""
    where = f'{source}: ' if source else ''
    if is_builtin(name):
        if name in ROS_BUILTIN and not isinstance(value, type(ROS_BUILTIN[name])):
            raise ConfigError(f'{where}node {node}: parameter {name}: expected '
                              f'{type(ROS_BUILTIN[name]).__name__}, got {value!r}')
        return value
    found = field_of(node, name)
    if found is None:
        raise ConfigError(f'{where}node {node}: unknown parameter {name!r} (the node\'s '
                          f'parameters: `laser-tracker config --write -`)')
    prefix, field = found
    try:
        return check_value(prefix, field, value)
    except ConfigError as exc:
        raise ConfigError(f'{where}node {node}: parameter {exc}') from None


@dataclass
class NodeParameters:
    """The validated parameters of one node: its sections and where each value came from."""

    node: str
    sections: dict[str, Any]           # prefix -> section dataclass instance
    sources: dict[str, str]            # dotted name -> file (or 'command line') that set it
    builtin: dict[str, Any]            # use_sim_time, qos_overrides.* as given

    def values(self) -> dict[str, Any]:
        """``{dotted name: value}`` of every parameter (defaults included)."""
        out = {}
        for prefix, section in self.sections.items():
            for key, value in to_dict(section).items():
                out[f'{prefix}.{key}' if prefix else key] = value
        return out


def read_files(paths: Iterable[str | Path]) -> list[ParameterEntry]:
    entries: list[ParameterEntry] = []
    for path in paths:
        entries.extend(read_parameter_file(path))
    return entries


def load(entries: Iterable[ParameterEntry] = (), overrides: Mapping[str, Any] | None = None,
         nodes: Iterable[str] | None = None, namespace: str | None = None,
         strict_entries: bool = True) -> dict[str, NodeParameters]:
    """Validate parameter-file entries (and ``-p`` style ``overrides``, applied to every node
    that has them) for ``nodes`` (default: all of ours) in ``namespace`` (None: any).

    Later entries override earlier ones, overrides override entries. With
    ``strict_entries``, an entry that configures none of our nodes (in any namespace) is an
    error, and so is a parameter that none of the nodes its entry configures has, or a bad
    value. ConfigError names the first problem in one line.
    """
    entries = list(entries)
    wanted = list(nodes) if nodes is not None else list(NODE_SECTIONS)
    if strict_entries:
        _check_entries(entries)
    out: dict[str, NodeParameters] = {}
    for node in wanted:
        raw: dict[str, tuple[Any, str]] = {}
        for entry in entries:
            if not entry.matches(node, namespace):
                continue
            wildcard = '*' in entry.key
            for name, value in entry.params.items():
                if wildcard and field_of(node, name) is None and not is_builtin(name):
                    continue     # a wildcard entry may carry parameters of other nodes
                raw[name] = (value, entry.source)
        for name, value in (overrides or {}).items():
            if field_of(node, name) is not None or is_builtin(name):
                raw[name] = (value, COMMAND_LINE)
        out[node] = _validate(node, raw)
    return out


def _check_entries(entries: list[ParameterEntry]) -> None:
    """Every entry configures one of our nodes (in some namespace) and every parameter of it
    belongs to a node it configures, with a valid value."""
    for entry in entries:
        matched = [n for n in NODE_SECTIONS if entry.matches(n, None)]
        if not matched:
            import difflib
            name = entry.key.rstrip('/').rpartition('/')[2]
            near = difflib.get_close_matches(name, list(NODE_SECTIONS), n=1, cutoff=0.6)
            raise ConfigError(f'{entry.source}: {entry.key!r} configures none of the nodes '
                              f'{", ".join(NODE_SECTIONS)}'
                              + (f'; did you mean {near[0]!r}?' if near else ''))
        for name, value in entry.params.items():
            owners = [n for n in matched if is_builtin(name) or field_of(n, name)]
            if not owners:
                node = matched[0] if len(matched) == 1 else entry.key
                raise ConfigError(f'{entry.source}: node {node}: unknown parameter {name!r}'
                                  f'{near_parameters(name)} '
                                  f"(the nodes' parameters: `laser-tracker config --write -`)")
            for node in owners:
                check_parameter(node, name, value, entry.source)


def _validate(node: str, raw: dict[str, tuple[Any, str]]) -> NodeParameters:
    sections_cls = NODE_SECTIONS[node]
    values: dict[str, dict[str, Any]] = {prefix: {} for prefix in sections_cls}
    sources: dict[str, str] = {}
    builtin: dict[str, Any] = {}
    for name, (value, source) in raw.items():
        checked = check_parameter(node, name, value, source)
        sources[name] = source
        if is_builtin(name):
            builtin[name] = checked
            continue
        prefix, _, key = name.rpartition('.')
        values[prefix][key] = checked
    sections = {}
    for prefix, cls in sections_cls.items():
        try:
            sections[prefix] = from_dict(cls, values[prefix], prefix)
        except ConfigError as exc:   # a rule across fields (e.g. scan angle and resolution)
            source = next((sources[n] for n in sources
                           if n.startswith(prefix)), '') if values[prefix] else ''
            raise ConfigError((f'{source}: ' if source else '') + f'node {node}: {exc}') \
                from None
    return NodeParameters(node, sections, sources, builtin)


def load_files(paths: Iterable[str | Path], nodes: Iterable[str] | None = None,
               namespace: str | None = None) -> dict[str, NodeParameters]:
    """:func:`load` of parameter files (in order; later files override earlier ones)."""
    return load(read_files(paths), nodes=nodes, namespace=namespace)


def pipeline_config(params: Mapping[str, NodeParameters]) -> PipelineConfig:
    """The PipelineConfig of loaded node parameters (sections of the replay nodes)."""
    sections = {}
    for node in PIPELINE_NODES:
        if node in params:
            sections.update({p: s for p, s in params[node].sections.items() if p})
    return PipelineConfig(**sections)
