"""Declare a configuration section as ROS parameters, from the same dataclass the core uses.

Every field becomes ``<section>.<field>`` with a ParameterDescriptor carrying its description
and range, so rclpy refuses an out-of-range value with a message (at start-up from a YAML file,
and at run time from ``ros2 param set``).
"""
from __future__ import annotations

import dataclasses

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from laser_tracker.config import ConfigError, describe, from_dict


def _descriptor(field: dataclasses.Field, default) -> ParameterDescriptor:
    meta = field.metadata
    text = meta.get('description', '')
    if meta.get('choices'):
        text += f' One of: {", ".join(map(str, meta["choices"]))}.'
    desc = ParameterDescriptor(description=text)
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


def declare_section(node, section_cls, section: str):
    """Declare every field of ``section_cls`` on ``node``; return the section built from them."""
    values = {}
    for name, field in describe(section_cls):
        default = field.default if field.default is not dataclasses.MISSING \
            else field.default_factory()
        full = f'{section}.{name}' if section else name
        values[name] = node.declare_parameter(full, default, _descriptor(field, default)).value
    try:
        return from_dict(section_cls, values, section)
    except ConfigError as exc:
        raise SystemExit(f'{node.get_name()}: bad parameter: {exc}') from None
