"""Message definitions of our topics' types, read from the installed interface files.

A rosbag2 MCAP file carries, per type, a schema text: the type's ``.msg`` file followed by
one block per nested type (a line of 80 ``=``, ``MSG: pkg/Type``, that type's ``.msg``
text), each dependency once, depth first. This module builds that text from the ``.msg``
files installed under ``<prefix>/share/<pkg>/msg/`` (the venv's prefix and every entry of
``AMENT_PREFIX_PATH``), and a ``rosbags`` typestore that knows our types, which gives the
RIHS01 type hashes (the same hashes rosidl writes into ``share/<pkg>/msg/<Type>.json``)
and a CDR (de)serializer that needs no rclpy.

Type names are the ROS 2 form ``pkg/msg/Type``; ``pkg/Type`` is accepted as input.
No rclpy import here.
"""
from __future__ import annotations

import functools
import json
import os
import pathlib
import re
import sys

from rosbags.typesys import Stores, get_typestore, get_types_from_msg
from rosbags.typesys.store import Typestore

SEPARATOR = "=" * 80
PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
#: Our packages whose types the typestore learns from the installed .msg files.
OWN_PACKAGES = ("thermal_comp_msgs",)


class MsgDefinitionError(LookupError):
    """A message type is unknown or its installed definition cannot be read."""


def normalize_type(type_name: str) -> str:
    """'pkg/Type' or 'pkg/msg/Type' -> 'pkg/msg/Type' (ValueError naming the value)."""
    parts = type_name.strip().split("/")
    if len(parts) == 2 and all(parts):
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and parts[1] == "msg" and parts[0] and parts[2]:
        return "/".join(parts)
    raise MsgDefinitionError(f"message type {type_name!r}: expected 'pkg/msg/Type' or 'pkg/Type'")


def share_dirs() -> list[pathlib.Path]:
    """Install prefixes' share/ folders to search: this interpreter's prefix first."""
    dirs = [pathlib.Path(sys.prefix) / "share"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(pathlib.Path(prefix) / "share")
    seen: list[pathlib.Path] = []
    for d in dirs:
        if d not in seen:
            seen.append(d)
    return seen


def interface_file(type_name: str, suffix: str = ".msg") -> pathlib.Path:
    """Path of the installed ``share/<pkg>/msg/<Type><suffix>`` file of a type."""
    pkg, _, name = normalize_type(type_name).split("/")
    for share in share_dirs():
        path = share / pkg / "msg" / f"{name}{suffix}"
        if path.is_file():
            return path
    raise MsgDefinitionError(f"message type {type_name!r}: no {name}{suffix} under "
                             f"{', '.join(str(d / pkg / 'msg') for d in share_dirs())}")


@functools.lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    """The installed ``.msg`` text of a type, as rosidl installed it (comments included)."""
    return interface_file(type_name).read_text()


_FIELD = re.compile(r"^\s*([A-Za-z][\w/]*)(\[[^\]]*\])?\s+\w+")


def field_types(type_name: str) -> list[str]:
    """Field types of a type in field order (constants skipped): primitive names as they
    are ('float64', 'string<=8'), nested types as 'pkg/msg/Type'."""
    pkg = normalize_type(type_name).split("/")[0]
    out: list[str] = []
    for line in msg_text(type_name).splitlines():
        line = line.split("#", 1)[0]
        m = _FIELD.match(line)
        if not m:
            continue
        words = line.split()
        if len(words) >= 2 and "=" in words[1]:  # constant definition "uint8 NAME=1"
            continue
        if len(words) >= 3 and words[2].startswith("="):  # constant "uint8 NAME = 1"
            continue
        base = m.group(1).split("<=")[0]
        if base in PRIMITIVES:
            out.append(base)
        elif base == "Header":
            out.append("std_msgs/msg/Header")
        elif "/" in base:
            out.append(normalize_type(base))
        else:
            out.append(f"{pkg}/msg/{base}")
    return out


def nested_types(type_name: str) -> list[str]:
    """Directly nested (non-primitive) field types of a type, in field order, once each."""
    out: list[str] = []
    for t in field_types(type_name):
        if t not in PRIMITIVES and t not in out:
            out.append(t)
    return out


def first_field_type(type_name: str) -> str | None:
    """Type of the first field (see :func:`field_types`), None for an empty message."""
    types = field_types(type_name)
    return types[0] if types else None


def dependency_order(type_name: str) -> list[str]:
    """All types a type depends on, depth first, each once (the type itself excluded)."""
    order: list[str] = []

    def visit(t: str) -> None:
        for dep in nested_types(t):
            if dep not in order:
                order.append(dep)
                visit(dep)

    visit(normalize_type(type_name))
    return order


@functools.lru_cache(maxsize=None)
def schema_text(type_name: str) -> str:
    """The rosbag2 / MCAP ``ros2msg`` schema text of a type (see module doc)."""
    full = normalize_type(type_name)
    parts = [msg_text(full).rstrip("\n")]
    for dep in dependency_order(full):
        pkg, _, name = dep.split("/")
        parts.append(f"{SEPARATOR}\nMSG: {pkg}/{name}\n{msg_text(dep).rstrip(chr(10))}")
    return "\n".join(parts) + "\n"


def installed_type_hash(type_name: str) -> str | None:
    """RIHS01 hash rosidl wrote for a type (``share/<pkg>/msg/<Type>.json``), if installed."""
    try:
        path = interface_file(type_name, ".json")
    except MsgDefinitionError:
        return None
    data = json.loads(path.read_text())
    full = normalize_type(type_name)
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == full:
            return entry.get("hash_string")
    return None


def own_message_types() -> list[str]:
    """'pkg/msg/Type' of every message installed by our interface packages."""
    types: list[str] = []
    for pkg in OWN_PACKAGES:
        for share in share_dirs():
            folder = share / pkg / "msg"
            if folder.is_dir():
                types += [f"{pkg}/msg/{p.stem}" for p in sorted(folder.glob("*.msg"))]
                break
    return types


@functools.lru_cache(maxsize=1)
def typestore() -> Typestore:
    """A Jazzy typestore that also knows our types (from their installed .msg files)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    add: dict = {}
    for t in own_message_types():
        add.update(get_types_from_msg(msg_text(t), t))
    store.register(add)
    return store


def ensure_known(type_name: str) -> str:
    """Normalize a type name and make sure the typestore can (de)serialize it."""
    full = normalize_type(type_name)
    store = typestore()
    if full not in store.types:
        try:
            text = msg_text(full)
        except MsgDefinitionError:
            raise MsgDefinitionError(f"message type {type_name!r} is not known to the typestore "
                                     f"and has no installed .msg file") from None
        add = dict(get_types_from_msg(text, full))
        for dep in dependency_order(full):
            if dep not in store.types:
                add.update(get_types_from_msg(msg_text(dep), dep))
        store.register(add)
    return full


def type_hash(type_name: str) -> str:
    """RIHS01 type hash computed from the definition (equals rosidl's, see tests)."""
    return typestore().hash_rihs01(ensure_known(type_name))
