"""Configuration declared once: dataclass fields carry default, description and range.

Each algorithm module declares its own section as a frozen dataclass whose fields are made
with :func:`param`. The same declaration, checked by the same :func:`check_value`, serves the
nodes (``laser_tracker.nodes.common`` declares each field as a ROS parameter with its
description and range, and validates start-up and live values with it), offline replay and
``laser-tracker config --check`` (through ``laser_tracker.parameters.load``), and the
committed ``config/laser_tracker.yaml`` (:func:`render_ros_yaml` of the defaults).

Parameter names are dotted ``section.field`` (ROS nests a YAML map into dotted names).
:func:`read_parameter_file` reads a ROS 2 parameter file and :meth:`ParameterEntry.matches`
applies ROS 2's rules for which node an entry configures.
"""
from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Mapping
from pathlib import Path
from dataclasses import dataclass
from typing import Any

import yaml

from laser_tracker.errors import LaserTrackerError


class ConfigError(LaserTrackerError, ValueError):
    """A configuration value or file that cannot be used; the message says which and why."""


def param(default: Any, description: str, *, min: float | None = None,
          max: float | None = None, choices: tuple | None = None,
          read_only: str | None = None) -> Any:
    """A configuration field: its default, what it means, and its allowed range or choices.

    ``read_only``: the reason the value cannot change while a node runs (declared read-only
    there); None = it can change at run time.
    """
    meta = {'description': description, 'min': min, 'max': max, 'choices': choices,
            'read_only': read_only}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def describe(section_cls) -> list[tuple[str, dataclasses.Field]]:
    """The fields of a section dataclass, in declaration order."""
    return [(f.name, f) for f in dataclasses.fields(section_cls)]


def field_default(field: dataclasses.Field) -> Any:
    return field.default if field.default is not dataclasses.MISSING else field.default_factory()


def check_value(section: str, field: dataclasses.Field, value: Any) -> Any:
    """Coerce ``value`` to the field's type and check its range; raise ConfigError if not.

    The same rules everywhere (parameter files, ``replay --config``, node start-up and live
    ``ros2 param set``): an integer is a fine float; a float with an integral value is a
    fine integer; booleans and strings must be exactly that.
    """
    name = f'{section}.{field.name}' if section else field.name
    default = field_default(field)
    meta = field.metadata
    try:
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise TypeError
        elif isinstance(default, int):
            if isinstance(value, (bool, str)) or not float(value).is_integer():
                raise TypeError
            value = int(value)
        elif isinstance(default, float):
            if isinstance(value, (bool, str)):
                raise TypeError
            value = float(value)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise TypeError
        elif isinstance(default, list):
            if isinstance(value, (str, bytes)):
                raise TypeError
            value = list(value)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f'{name}: expected {_type_name(default)}, got {value!r}') from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f'{name}: must be finite, got {value!r}')
    if meta.get('min') is not None and value < meta['min']:
        raise ConfigError(f'{name}: {value!r} is below the minimum {meta["min"]}')
    if meta.get('max') is not None and value > meta['max']:
        raise ConfigError(f'{name}: {value!r} is above the maximum {meta["max"]}')
    if meta.get('choices') is not None and value not in meta['choices']:
        raise ConfigError(f'{name}: {value!r} is not one of {list(meta["choices"])}')
    return value


def _type_name(default: Any) -> str:
    return {bool: 'a boolean', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list'}.get(type(default), type(default).__name__)


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


@dataclass(frozen=True)
class ParameterEntry:
    """One node entry of a ROS 2 parameter file: ``key: {ros__parameters: {...}}``.

    ``key`` is the node name as written (``tracking``, ``/tracking``, ``/robot1/tracking``,
    ``/**/tracking``, ``/**``); ``params`` maps dotted parameter names to values.
    """

    key: str
    params: dict
    source: str

    def matches(self, node: str, namespace: str | None = None) -> bool:
        """Whether this entry applies to node ``node`` in ``namespace`` (ROS 2 rules).

        A key without a leading slash is a node in the root namespace (``tracking`` is
        ``/tracking``); ``*`` stands for one name token, ``**`` for any number of them.
        ``namespace=None`` means "whichever namespace the node will run in" (offline use):
        the key's namespace part then matches anything and only the node name counts.
        """
        fqn_key = self.key if self.key.startswith('/') else '/' + self.key
        tokens = [t for t in fqn_key.split('/') if t]
        if namespace is None:
            if not tokens:
                return False
            if tokens[-1] == '**':
                return True
            return _token_pattern(tokens[-1]).fullmatch(node) is not None
        ns_tokens = [t for t in namespace.split('/') if t]
        return _key_pattern(tokens).fullmatch('/' + '/'.join(ns_tokens + [node])) is not None


def _token_pattern(token: str) -> re.Pattern:
    return re.compile('[^/]*'.join(re.escape(p) for p in token.split('*')))


def _key_pattern(tokens: list[str]) -> re.Pattern:
    parts = []
    for t in tokens:
        if t == '**':
            parts.append('(/[^/]+)*')
        else:
            parts.append('/' + '[^/]*'.join(re.escape(p) for p in t.split('*')))
    return re.compile(''.join(parts) or '/')


def read_parameter_file(path: str | Path) -> list[ParameterEntry]:
    """The node entries of a ROS 2 parameter file, in file order.

    ConfigError (one line naming the file) when it cannot be read, is not YAML, or is not a
    map of ``node: {ros__parameters: {...}}`` entries.
    """
    path = Path(path)
    try:
        text = path.read_text()
        data = yaml.safe_load(text)
    except IsADirectoryError:
        raise ConfigError(f'{path}: is a folder, not a parameter file') from None
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f'{path}: not a text file (byte {exc.start}: {exc.reason})') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise ConfigError(f'{path}: not valid YAML{where}: {problem}') from None
    if data is None:
        return []
    if not isinstance(data, Mapping):
        raise ConfigError(f'{path}: expected a map of node names at the top level, got '
                          f'{type(data).__name__}')
    entries = []
    for key, body in data.items():
        if not isinstance(body, Mapping) or 'ros__parameters' not in body:
            raise ConfigError(f'{path}: entry {key!r} has no ros__parameters map')
        params = body['ros__parameters'] or {}
        if not isinstance(params, Mapping):
            raise ConfigError(f'{path}: {key}: ros__parameters is not a map')
        entries.append(ParameterEntry(str(key), flatten(params), str(path)))
    return entries


def render_ros_yaml(nodes: Mapping[str, Mapping[str, Any]], header: str = '') -> str:
    """``{node: {dotted.param: value}}`` -> the text of a ROS 2 parameter file."""
    doc = {node: {'ros__parameters': unflatten(params)} for node, params in nodes.items()}
    body = yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)
    return (header + body) if header else body
