"""ROS 2 message definitions as rosbag2 stores them in an MCAP schema.

rclpy's message classes do not carry their .msg text, but every interface package
installs it as share/<pkg>/msg/<Type>.msg (the PyPI wheels do too, under the
venv's share/). ``full_text`` concatenates a type's text with its dependencies the
way rosbag2's LocalMessageDefinitionSource::get_full_text does (Jazzy), so the
schema bytes match what ``ros2 bag record`` would write:

    <root .msg text>
    ================================================================================
    MSG: <pkg>/<Type>
    <its text, followed by its own not-yet-seen dependencies, depth first>

Dependencies are the first token of each line that is not a primitive type,
in sorted order; a bare ``Type`` means the same package. Schema encoding: ``ros2msg``.
``type_hash`` reads the RIHS01 type-description hash from share/<pkg>/msg/<Type>.json.
"""
from __future__ import annotations

import functools
import json
import os
from pathlib import Path
import re
import sys

SCHEMA_ENCODING = 'ros2msg'
DELIMITER = '=' * 80 + '\n'

# the regular expressions and primitive set of rosbag2's local_message_definition_source.cpp
PACKAGE_TYPENAME = re.compile(r'^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$')
MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
PRIMITIVE_TYPES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                             'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'})
MAX_DEPTH = 50


class DefinitionNotFound(LookupError):
    """No share/<pkg>/msg/<Type>.msg for a type on any searched prefix."""


def share_prefixes() -> list[Path]:
    """Where to look for share/<pkg>: $AMENT_PREFIX_PATH, then this Python's prefix (venv)."""
    prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes += [Path(sys.prefix), Path(sys.base_prefix)]
    out = []
    for p in prefixes:
        if p not in out and (p / 'share').is_dir():
            out.append(p)
    return out


def split_type(type_name: str) -> tuple[str, str]:
    """'geometry_msgs/msg/Pose' or 'geometry_msgs/Pose' -> ('geometry_msgs', 'Pose')."""
    m = PACKAGE_TYPENAME.match(type_name)
    if not m:
        raise DefinitionNotFound(f"type name '{type_name}' is not <package>/[msg/]<Type>")
    return m.group(1), m.group(2)


def _interface_file(type_name: str, suffix: str) -> Path:
    package, name = split_type(type_name)
    for prefix in share_prefixes():
        path = prefix / 'share' / package / 'msg' / f'{name}{suffix}'
        if path.is_file():
            return path
    raise DefinitionNotFound(f'no share/{package}/msg/{name}{suffix} under {share_prefixes()}')


@functools.lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    """The .msg file of a type, as installed."""
    return _interface_file(type_name, '.msg').read_text()


def dependencies(text: str, package: str) -> list[str]:
    """Non-primitive field types of a .msg text, sorted, as 'pkg/Type'."""
    deps = set()
    for m in MSG_FIELD_TYPE.finditer(text):
        t = m.group(1)
        if t in PRIMITIVE_TYPES:
            continue
        deps.add(t if '/' in t else f'{package}/{t}')
    return sorted(deps)


@functools.lru_cache(maxsize=None)
def full_text(type_name: str) -> str:
    """The concatenated ros2msg definition of a type and everything it uses."""
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise RecursionError(f'reached max recursion depth resolving {type_name}')
        package, _ = split_type(name)
        text = msg_text(name)
        out = text
        for dep in dependencies(text, package):
            if dep not in seen:
                seen.add(dep)
                out += '\n' + DELIMITER + f'MSG: {dep}\n' + append(dep, depth - 1)
        return out

    return append(type_name, MAX_DEPTH)


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """'RIHS01_<hex>' of a type from its installed type description, '' if there is none."""
    package, name = split_type(type_name)
    try:
        data = json.loads(_interface_file(type_name, '.json').read_text())
    except (DefinitionNotFound, ValueError, OSError):
        return ''
    full = f'{package}/msg/{name}'
    for entry in data.get('type_hashes', []):
        if entry.get('type_name') == full:
            return str(entry.get('hash_string', ''))
    return ''
