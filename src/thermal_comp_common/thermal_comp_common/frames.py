"""The coordinate frames of a machine (REP 103/105 style), from its twin or cell description.

One fixed root, ``machine_base`` (the machine's coordinate system: x, y, z in metres), a frame
per body of the thermal network (``body_<node>``) and a frame per positioned sensor
(``sensor_<id>``). A sensor measuring one body hangs from that body's frame; any other sensor
(a boundary such as the hall air, or a combination of nodes) hangs from the root. The lumped
twin has no geometry of its bodies: a body sits at the root unless its description gives a
``position_mm``, so a sensor's transform from the root is its ``position_mm`` either way.

ROS-free: the static-TF publisher, the message headers and the rerun 3D view all take the
transforms from :func:`frame_tree`, so they cannot disagree.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

MACHINE_BASE_FRAME = "machine_base"
IDENTITY_ROTATION = (0.0, 0.0, 0.0, 1.0)   # quaternion x, y, z, w


class FrameError(ValueError):
    """A description cannot be turned into frames; the message names the field and value."""


@dataclass(frozen=True)
class FrameTransform:
    """A static transform: ``child`` expressed in ``parent`` (translation in m, rotation x, y, z, w)."""
    parent: str
    child: str
    translation_m: tuple[float, float, float]
    rotation_xyzw: tuple[float, float, float, float] = IDENTITY_ROTATION


def body_frame(node: str, prefix: str = "") -> str:
    """The frame id of a body (a node of the thermal network)."""
    return f"{prefix}body_{node}"


def sensor_frame(sensor_id: str, prefix: str = "") -> str:
    """The frame id of a sensor."""
    return f"{prefix}sensor_{sensor_id}"


def _position_m(value: Any, field: str) -> tuple[float, float, float]:
    """``[x, y, z]`` in mm -> metres, or a FrameError naming the field."""
    try:
        xyz = tuple(float(v) / 1000.0 for v in value)
    except (TypeError, ValueError):
        xyz = ()
    if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
        raise FrameError(f"{field}: {value!r} is not [x, y, z] in mm (three finite numbers)")
    return xyz  # type: ignore[return-value]


def _check_prefix(prefix: str) -> None:
    if not isinstance(prefix, str) or prefix.startswith("/") or any(c.isspace() for c in prefix):
        raise FrameError(f"prefix: {prefix!r} is not a frame prefix (no leading '/', no spaces)")


def frame_tree(description: Mapping[str, Any], prefix: str = "") -> list[FrameTransform]:
    """The static transforms of a twin or sensor-layout description (a parsed YAML mapping).

    ``nodes: {name: {position_mm?: [x, y, z]}}`` gives the bodies, ``sensors: {id: {of?: node,
    position_mm?: [x, y, z]}}`` the sensors; sensors without ``position_mm`` get no frame (their
    place is unknown). Parents come before their children; names are sorted, so the list is
    the same for the same description.
    """
    _check_prefix(prefix)
    if not isinstance(description, Mapping):
        raise FrameError(f"description: {type(description).__name__} is not a mapping")
    nodes = description.get("nodes") or {}
    sensors = description.get("sensors") or {}
    if not isinstance(nodes, Mapping):
        raise FrameError(f"nodes: {type(nodes).__name__} is not a mapping")
    if not isinstance(sensors, Mapping):
        raise FrameError(f"sensors: {type(sensors).__name__} is not a mapping")
    root = prefix + MACHINE_BASE_FRAME
    out: list[FrameTransform] = []
    body_pos: dict[str, tuple[float, float, float]] = {}
    for name in sorted(nodes, key=str):
        spec = nodes[name] if isinstance(nodes[name], Mapping) else {}
        pos = spec.get("position_mm")
        body_pos[str(name)] = (0.0, 0.0, 0.0) if pos is None else _position_m(pos, f"nodes.{name}.position_mm")
        out.append(FrameTransform(root, body_frame(str(name), prefix), body_pos[str(name)]))
    for sid in sorted(sensors, key=str):
        spec = sensors[sid]
        if not isinstance(spec, Mapping) or spec.get("position_mm") is None:
            continue
        pos = _position_m(spec["position_mm"], f"sensors.{sid}.position_mm")
        of = spec.get("of")
        if isinstance(of, str) and of in body_pos:
            base = body_pos[of]
            rel = tuple(p - b for p, b in zip(pos, base))
            out.append(FrameTransform(body_frame(of, prefix), sensor_frame(str(sid), prefix), rel))  # type: ignore[arg-type]
        else:
            out.append(FrameTransform(root, sensor_frame(str(sid), prefix), pos))
    return out


def _rotate(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> tuple[float, float, float]:
    """Rotate vector v by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx))


def _compose(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Quaternion product a * b (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def positions_in_root(transforms: list[FrameTransform]) -> dict[str, tuple[float, float, float]]:
    """Every frame's origin in the root frame (m), composing the chain of transforms.

    Raises FrameError if a parent is never defined (other than the single root) or a frame has
    two parents: a tree is what TF needs.
    """
    parents = {t.parent for t in transforms}
    children = [t.child for t in transforms]
    if len(set(children)) != len(children):
        dup = sorted({c for c in children if children.count(c) > 1})
        raise FrameError(f"frames: {', '.join(dup)} defined twice")
    roots = parents - set(children)
    if len(roots) > 1:
        raise FrameError(f"frames: more than one root ({', '.join(sorted(roots))})")
    pose: dict[str, tuple[tuple[float, float, float], tuple[float, float, float, float]]] = {
        r: ((0.0, 0.0, 0.0), IDENTITY_ROTATION) for r in roots}
    pending = list(transforms)
    while pending:
        ready = [t for t in pending if t.parent in pose]
        if not ready:
            raise FrameError(f"frames: {pending[0].child} hangs from {pending[0].parent}, which is in a cycle")
        for t in ready:
            p, q = pose[t.parent]
            d = _rotate(q, t.translation_m)
            pose[t.child] = ((p[0] + d[0], p[1] + d[1], p[2] + d[2]), _compose(q, t.rotation_xyzw))
            pending.remove(t)
    return {name: p for name, (p, _) in pose.items()}
