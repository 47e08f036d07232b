"""A node's parameters: validated by the package's one loader, declared with their
descriptions and ranges, and changeable at run time.

At start-up :class:`LiveParameters` takes the values rclpy resolved for this node (parameter
files and ``-p`` overrides, matched to the node's name and namespace by ROS 2's rules),
validates them with ``laser_tracker.parameters`` (the same checks as ``replay --config``
and ``laser-tracker config --check``: an integer is a fine float, ranges, choices, unknown
names refused) and raises ConfigError naming the file, node and parameter. The entries of the
parameter files are checked too (an entry that configures none of our nodes is an error).

Every field is then declared as ``<section>.<field>`` with a ParameterDescriptor carrying its
description and range (``ros2 param describe``). At run time ``ros2 param set`` is validated
by the same checks (a refused value answers unsuccessful with the reason), and an accepted
change is handed to the node's ``apply`` callback with the new sections, which rebuilds or
updates its stage from the next message. Parameters that cannot change while running are
declared read-only, their description saying why.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)

from laser_tracker import parameters as registry
from laser_tracker.config import ConfigError, describe, field_default, from_dict

#: Parameter files given on the command line of this process (``--params-file``), for
#: naming the file in errors; filled by ``common.run``.
PARAMETER_FILES: list[str] = []
#: (file, entry, namespace) already warned about, so nodes sharing a process warn once.
_WARNED: set[tuple[str, str, str]] = set()


def _descriptor(field: dataclasses.Field, default) -> ParameterDescriptor:
    meta = field.metadata
    text = meta.get('description', '')
    if meta.get('choices'):
        text += f' One of: {", ".join(map(str, meta["choices"]))}.'
    read_only = meta.get('read_only')
    if read_only:
        text += f' Read-only while running: {read_only}.'
    # dynamic_typing: the package's own checks decide (an integer is a fine float).
    desc = ParameterDescriptor(description=text, read_only=bool(read_only),
                               dynamic_typing=True)
    lo, hi = meta.get('min'), meta.get('max')
    if (lo is not None or hi is not None) and not isinstance(default, bool):
        if isinstance(default, int):
            desc.integer_range = [IntegerRange(from_value=int(lo if lo is not None else -2**63),
                                               to_value=int(hi if hi is not None else 2**63 - 1),
                                               step=0)]
        elif isinstance(default, float):
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(lo if lo is not None else -1e308),
                to_value=float(hi if hi is not None else 1e308), step=0.0)]
    return desc


def _source_files(node) -> list:
    try:
        return registry.read_files(PARAMETER_FILES)
    except ConfigError:
        raise
    except Exception:  # noqa: BLE001 - only used to name the file in messages
        return []


class LiveParameters:
    """Declares a node's parameters and keeps ``sections`` current (see the module doc).

    ``apply(sections)`` is called after every accepted run-time change with
    ``{prefix: section instance}``; it must not raise for valid sections.
    """

    def __init__(self, node, node_name: str,
                 apply: Callable[[dict], None] | None = None):
        self.node = node
        self.node_name = node_name
        self.apply = apply
        namespace = node.get_namespace()
        entries = _source_files(node)
        overrides = {name: p.value for name, p in node._parameter_overrides.items()}
        # What rclpy resolved for this node, each value attributed to its file (or -p).
        from_files = registry.load(entries, nodes=[node_name], namespace=namespace)
        # A name no node of ours has is an error; one of another of our nodes is for that
        # node (``-p`` reaches every node of a process, e.g. in laser_tracker_all).
        unknown = sorted(n for n in overrides
                         if registry.field_of(node_name, n) is None
                         and not registry.is_builtin(n)
                         and not any(registry.field_of(other, n) is not None
                                     for other in registry.NODE_SECTIONS))
        if unknown:
            src = from_files[node_name].sources.get(unknown[0]) or registry.COMMAND_LINE
            raise ConfigError(f'{src}: no node has a parameter {unknown[0]!r}'
                              f'{registry.near_parameters(unknown[0])} (every parameter: '
                              '`laser-tracker config --write -`)')
        for entry in registry.entries_for_other_namespaces(entries, node_name, namespace):
            if (entry.source, entry.key, namespace) not in _WARNED:
                _WARNED.add((entry.source, entry.key, namespace))
                node.get_logger().warning(
                    registry.other_namespace_warning(entry, node_name, namespace))
        raw = {n: v for n, v in overrides.items()
               if registry.field_of(node_name, n) is not None}
        sources = dict(from_files[node_name].sources)
        for name in raw:
            sources.setdefault(name, registry.COMMAND_LINE)
        loaded = registry.load(
            [registry.ParameterEntry('/**', {n: raw[n]}, sources[n]) for n in raw],
            nodes=[node_name], strict_entries=False)[node_name]
        self.sections = loaded.sections
        for prefix, cls in registry.NODE_SECTIONS[node_name].items():
            section = self.sections[prefix]
            for name, field in describe(cls):
                full = f'{prefix}.{name}' if prefix else name
                node.declare_parameter(full, getattr(section, name),
                                       _descriptor(field, field_default(field)),
                                       ignore_override=True)
        self._pending: dict | None = None
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._changed)

    def _validate(self, params) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        try:
            self._pending = self._sections_with(values)
        except ConfigError as exc:
            self._pending = None
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _sections_with(self, changes: dict) -> dict:
        """The sections after ``changes`` (name -> value), validated; ConfigError if not."""
        updated = {prefix: dataclasses.asdict(s) for prefix, s in self.sections.items()}
        for name, value in changes.items():
            if registry.is_builtin(name):
                continue
            checked = registry.check_parameter(self.node_name, name, value)
            prefix, _, key = name.rpartition('.')
            updated[prefix][key] = checked
        cls = registry.NODE_SECTIONS[self.node_name]
        out = {}
        for prefix, values in updated.items():
            try:
                out[prefix] = from_dict(cls[prefix], values, prefix)
            except ConfigError as exc:
                raise ConfigError(f'node {self.node_name}: {exc}') from None
        return out

    def _changed(self, params) -> None:
        if self._pending is None:
            return
        new, self._pending = self._pending, None
        if new == self.sections:
            return
        self.sections = new
        if self.apply is not None:
            self.apply(new)
