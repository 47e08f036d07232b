"""Configuration declared once: dataclass fields carry default, description and range.

Each algorithm module declares its own section as a frozen dataclass whose fields are made
with :func:`param`. The same declaration serves

* offline tools (``from_dict`` / ``load_ros_yaml``: the ROS parameter file read without ROS),
* the nodes (``laser_tracker.nodes.params`` declares every field as a ROS parameter with a
  ``ParameterDescriptor`` carrying the description and range, so rclpy refuses bad values),
* the committed ``config/laser_tracker.yaml`` (``render_ros_yaml`` writes it from the defaults).

Parameter names are dotted ``section.field`` (ROS nests a YAML map into dotted names).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from laser_tracker.errors import LaserTrackerError


class ConfigError(LaserTrackerError, ValueError):
    """A configuration value or file that cannot be used; the message says which and why."""


def param(default: Any, description: str, *, min: float | None = None,
          max: float | None = None, choices: tuple | None = None) -> Any:
    """A configuration field: its default, what it means, and its allowed range or choices."""
    meta = {'description': description, 'min': min, 'max': max, 'choices': choices}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def describe(section_cls) -> list[tuple[str, dataclasses.Field]]:
    """The fields of a section dataclass, in declaration order."""
    return [(f.name, f) for f in dataclasses.fields(section_cls)]


def check_value(section: str, field: dataclasses.Field, value: Any) -> Any:
    """Coerce ``value`` to the field's type and check its range; raise ConfigError if not."""
    name = f'{section}.{field.name}' if section else field.name
    default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
    meta = field.metadata
    try:
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise TypeError
        elif isinstance(default, int):
            if isinstance(value, bool) or not float(value).is_integer():
                raise TypeError
            value = int(value)
        elif isinstance(default, float):
            if isinstance(value, bool):
                raise TypeError
            value = float(value)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise TypeError
        elif isinstance(default, list):
            value = list(value)
    except (TypeError, ValueError):
        raise ConfigError(f'{name}: expected {type(default).__name__}, got {value!r}') from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f'{name}: must be finite, got {value!r}')
    if meta.get('min') is not None and value < meta['min']:
        raise ConfigError(f'{name}: {value!r} is below the minimum {meta["min"]}')
    if meta.get('max') is not None and value > meta['max']:
        raise ConfigError(f'{name}: {value!r} is above the maximum {meta["max"]}')
    if meta.get('choices') is not None and value not in meta['choices']:
        raise ConfigError(f'{name}: {value!r} is not one of {list(meta["choices"])}')
    return value


def from_dict(section_cls, values: Mapping[str, Any] | None, section: str = ''):
    """Build a section from a mapping; unknown keys and out-of-range values raise ConfigError."""
    values = dict(values or {})
    fields = dict(describe(section_cls))
    unknown = sorted(set(values) - set(fields))
    if unknown:
        where = f' in section {section!r}' if section else ''
        raise ConfigError(f'unknown parameter(s){where}: {", ".join(unknown)}; '
                          f'known: {", ".join(fields)}')
    kwargs = {k: check_value(section, fields[k], v) for k, v in values.items()}
    return section_cls(**kwargs)


def to_dict(config) -> dict[str, Any]:
    """A section (or a composite of sections) as a plain nested dict."""
    return dataclasses.asdict(config)


def flatten(mapping: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested dict -> dotted names, as ROS turns a YAML map into parameter names."""
    flat: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted names -> nested dict (the inverse of :func:`flatten`)."""
    nested: dict[str, Any] = {}
    for name, value in flat.items():
        node = nested
        *parents, leaf = name.split('.')
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return nested


def read_ros_yaml(path: str | Path) -> dict[str, dict[str, Any]]:
    """A ROS 2 parameter file as ``{node_name: {dotted.param: value}}``.

    Accepts ``node: {ros__parameters: {...}}`` entries (also ``/node`` and ``/**`` keys).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f'{path}: not a text file (byte {exc.start}: {exc.reason})') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: not valid YAML: {exc}') from None
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError(f'{path}: expected a map of node names at the top level')
    nodes: dict[str, dict[str, Any]] = {}
    for node_name, body in data.items():
        if not isinstance(body, Mapping) or 'ros__parameters' not in body:
            raise ConfigError(f'{path}: entry {node_name!r} has no ros__parameters map')
        params = body['ros__parameters'] or {}
        if not isinstance(params, Mapping):
            raise ConfigError(f'{path}: {node_name}.ros__parameters is not a map')
        nodes[str(node_name).lstrip('/')] = flatten(params)
    return nodes


def render_ros_yaml(nodes: Mapping[str, Mapping[str, Any]], header: str = '') -> str:
    """``{node: {dotted.param: value}}`` -> the text of a ROS 2 parameter file."""
    doc = {node: {'ros__parameters': unflatten(params)} for node, params in nodes.items()}
    body = yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    return (header + body) if header else body
