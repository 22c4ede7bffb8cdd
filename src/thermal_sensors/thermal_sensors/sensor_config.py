"""Sensor configuration: the ``sensors`` (and optional ``modbus``) section of a cell YAML.

The schema, with an example, is in docs/sensors.md ("The sensor YAML"); the section may also
sit under a ``temperature_publisher`` key. Every validation error is a
:class:`SensorConfigError` naming the key path and the bad value.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field
from typing import Any, Mapping

import yaml

from thermal_comp_common.sensor_readings import PLAUSIBLE_RANGE_DEGC
from thermal_sensors.gain_offset import GainOffset

REGISTER_KINDS = ("input", "holding")
REGISTER_TYPES = ("int16", "uint16")
TRANSPORTS = ("tcp", "rtu", "rtu_over_tcp")
PARITIES = ("N", "E", "O")


class SensorConfigError(ValueError):
    """The sensor configuration is invalid; the message names the key and the value."""


@dataclass(frozen=True)
class ModbusRegister:
    """Where one sensor's value lives on a Modbus module and how to decode it."""

    module: str
    address: int
    register: str = "input"          # "input" (function 4) or "holding" (function 3)
    type: str = "int16"              # "int16" (two's complement) or "uint16"
    scale: float = 0.1               # degC per count (0.1: tenths of degC)
    offset_degc: float = 0.0         # value = raw * scale + offset_degc
    fault_raw: int | None = None     # raw value the module sends for a broken sensor

    @property
    def signed(self) -> bool:
        return self.type == "int16"

    @property
    def effective_fault_raw(self) -> int:
        """The fault code: configured, else the type's extreme (-32768 or 65535)."""
        if self.fault_raw is not None:
            return self.fault_raw
        return -32768 if self.signed else 65535


@dataclass(frozen=True)
class ModbusModule:
    """One Modbus device (unit id) and the connection it is reached through."""

    name: str
    transport: str = "tcp"           # tcp | rtu (serial line) | rtu_over_tcp (gateway)
    host: str = "127.0.0.1"
    port: int = 502
    serial_port: str = ""            # rtu: /dev/ttyUSB0 or a pyserial URL (socket://h:p)
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    unit_id: int = 1
    timeout_s: float = 0.5           # per read; a module silent this long -> its sensors FAILED
    poll_period_s: float = 1.0
    reconnect_min_s: float = 0.5     # first back-off after a failure, doubled up to max
    reconnect_max_s: float = 30.0

    @property
    def link_key(self) -> tuple:
        """Modules with the same key share one connection (an RS-485 bus or a gateway)."""
        if self.transport == "rtu":
            return ("rtu", self.serial_port, self.baudrate, self.parity, self.stopbits, self.bytesize)
        return (self.transport, self.host, self.port)


@dataclass(frozen=True)
class SensorSpec:
    """One published temperature sensor."""

    id: str
    channel: str
    range_degc: tuple[float, float] = PLAUSIBLE_RANGE_DEGC
    stale_after_s: float = 0.0
    stale_tolerance_degc: float = 0.0
    gain_offset: GainOffset = field(default_factory=GainOffset)   # YAML key ``calibration``
    modbus: ModbusRegister | None = None

    @property
    def csv_column(self) -> str:
        return self.channel if self.channel.endswith("_c") else f"{self.channel}_c"


@dataclass(frozen=True)
class SensorConfig:
    sensors: tuple[SensorSpec, ...]
    modules: tuple[ModbusModule, ...] = ()
    max_age_s: float = 60.0
    source: str = ""

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return tuple(s.id for s in self.sensors)

    def module(self, name: str) -> ModbusModule:
        for m in self.modules:
            if m.name == name:
                return m
        raise KeyError(name)


# --------------------------------------------------------------------------------------
def _fail(where: str, key: str, value: Any, why: str) -> SensorConfigError:
    return SensorConfigError(f"{where}{key}: {value!r} {why}")


def _unique(keys: list, where: str, key: str, why: str, values: list | None = None) -> dict:
    """``{key: index}``; the first repeated key fails naming ``where[i].key``, its value (``values[i]``,
    default the key) and ``why`` with ``{first}`` the index of the earlier one."""
    seen: dict = {}
    for i, k in enumerate(keys):
        if k in seen:
            raise _fail(f"{where}[{i}].", key, k if values is None else values[i], why.format(first=seen[k]))
        seen[k] = i
    return seen


def _number(d: Mapping, key: str, default: float | None, where: str, lo: float | None = None,
            hi: float | None = None, positive: bool = False) -> float:
    if key not in d:
        if default is None:
            raise SensorConfigError(f"{where}{key}: missing (required)")
        return float(default)
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise _fail(where, key, v, "is not a finite number")
    v = float(v)
    if positive and v <= 0:
        raise _fail(where, key, v, "must be > 0")
    if lo is not None and v < lo:
        raise _fail(where, key, v, f"is below the minimum {lo}")
    if hi is not None and v > hi:
        raise _fail(where, key, v, f"is above the maximum {hi}")
    return v


def _integer(d: Mapping, key: str, default: int | None, where: str, lo: int, hi: int) -> int:
    if key not in d:
        if default is None:
            raise SensorConfigError(f"{where}{key}: missing (required)")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int):
        raise _fail(where, key, v, "is not an integer")
    if not lo <= v <= hi:
        raise _fail(where, key, v, f"is outside {lo}..{hi}")
    return v


def _string(d: Mapping, key: str, default: str | None, where: str,
            choices: tuple[str, ...] | None = None) -> str:
    if key not in d:
        if default is None:
            raise SensorConfigError(f"{where}{key}: missing (required)")
        return default
    v = d[key]
    if not isinstance(v, str) or not v.strip():
        raise _fail(where, key, v, "is not a non-empty string")
    if choices is not None and v not in choices:
        raise _fail(where, key, v, f"is not one of {list(choices)}")
    return v


def _check_keys(d: Mapping, allowed: set[str], where: str) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise SensorConfigError(f"{where}{unknown[0]}: unknown key (allowed: {sorted(allowed)})")


def _mapping(v: Any, where: str) -> Mapping:
    if not isinstance(v, Mapping):
        raise SensorConfigError(f"{where.rstrip('.')}: expected a mapping, got {v!r}")
    return v


def _parse_register(d: Any, where: str) -> ModbusRegister:
    d = _mapping(d, where)
    _check_keys(d, {"module", "address", "register", "type", "scale", "offset_degc", "fault_raw"}, where)
    typ = _string(d, "type", "int16", where, REGISTER_TYPES)
    scale = _number(d, "scale", 0.1, where)
    if scale == 0:
        raise _fail(where, "scale", d.get("scale"), "must not be 0")
    fault = None
    if "fault_raw" in d and d["fault_raw"] is not None:
        fault = _integer(d, "fault_raw", None, where, *((-32768, 32767) if typ == "int16" else (0, 65535)))
    return ModbusRegister(
        module=_string(d, "module", None, where),
        address=_integer(d, "address", None, where, 0, 65535),
        register=_string(d, "register", "input", where, REGISTER_KINDS),
        type=typ, scale=scale, offset_degc=_number(d, "offset_degc", 0.0, where), fault_raw=fault)


def _parse_sensor(d: Any, where: str) -> SensorSpec:
    d = _mapping(d, where)
    _check_keys(d, {"id", "channel", "range_degc", "stale_after_s", "stale_tolerance_degc",
                    "calibration", "modbus"}, where)
    sid = _string(d, "id", None, where)
    rng = d.get("range_degc", list(PLAUSIBLE_RANGE_DEGC))
    if (not isinstance(rng, (list, tuple)) or len(rng) != 2
            or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in rng)
            or not rng[0] < rng[1]):
        raise _fail(where, "range_degc", rng, "must be [low, high] with finite low < high")
    cal = GainOffset()
    if "calibration" in d:
        cw = f"{where}calibration."
        c = _mapping(d["calibration"], cw)
        _check_keys(c, {"offset_degc", "gain"}, cw)
        gain = _number(c, "gain", 1.0, cw)
        if gain == 0:
            raise _fail(cw, "gain", c.get("gain"), "must not be 0")
        cal = GainOffset(offset_degc=_number(c, "offset_degc", 0.0, cw), gain=gain)
    reg = _parse_register(d["modbus"], f"{where}modbus.") if "modbus" in d else None
    return SensorSpec(
        id=sid, channel=_string(d, "channel", sid, where),
        range_degc=(float(rng[0]), float(rng[1])),
        stale_after_s=_number(d, "stale_after_s", 0.0, where, lo=0.0),
        stale_tolerance_degc=_number(d, "stale_tolerance_degc", 0.0, where, lo=0.0),
        gain_offset=cal, modbus=reg)


def _parse_module(d: Any, where: str) -> ModbusModule:
    d = _mapping(d, where)
    _check_keys(d, {"name", "transport", "host", "port", "serial_port", "baudrate", "parity",
                    "stopbits", "bytesize", "unit_id", "timeout_s", "poll_period_s",
                    "reconnect_min_s", "reconnect_max_s"}, where)
    transport = _string(d, "transport", "tcp", where, TRANSPORTS)
    m = ModbusModule(
        name=_string(d, "name", None, where), transport=transport,
        host=_string(d, "host", "127.0.0.1", where),
        port=_integer(d, "port", 502, where, 1, 65535),
        serial_port=_string(d, "serial_port", None, where) if transport == "rtu" else "",
        baudrate=_integer(d, "baudrate", 19200, where, 300, 4_000_000),
        parity=_string(d, "parity", "N", where, PARITIES),
        stopbits=_integer(d, "stopbits", 1, where, 1, 2),
        bytesize=_integer(d, "bytesize", 8, where, 7, 8),
        unit_id=_integer(d, "unit_id", 1, where, 0, 247),
        timeout_s=_number(d, "timeout_s", 0.5, where, positive=True, hi=60.0),
        poll_period_s=_number(d, "poll_period_s", 1.0, where, positive=True),
        reconnect_min_s=_number(d, "reconnect_min_s", 0.5, where, positive=True),
        reconnect_max_s=_number(d, "reconnect_max_s", 30.0, where, positive=True))
    if m.reconnect_max_s < m.reconnect_min_s:
        raise _fail(where, "reconnect_max_s", m.reconnect_max_s,
                    f"is below reconnect_min_s {m.reconnect_min_s}")
    return m


def parse_sensor_config(doc: Any, source: str = "") -> SensorConfig:
    """Validate a parsed YAML document (the mapping holding ``sensors``)."""
    prefix = f"{source}: " if source else ""
    if isinstance(doc, Mapping) and "sensors" not in doc and isinstance(doc.get("temperature_publisher"), Mapping):
        doc = doc["temperature_publisher"]
        prefix += "temperature_publisher."
    doc = _mapping(doc, prefix or "sensor config")
    _check_keys(doc, {"sensors", "modbus", "max_age_s"}, prefix)
    raw_sensors = doc.get("sensors")
    if not isinstance(raw_sensors, list) or not raw_sensors:
        raise _fail(prefix, "sensors", raw_sensors, "must be a non-empty list of sensors")
    sensors = tuple(_parse_sensor(s, f"{prefix}sensors[{i}].") for i, s in enumerate(raw_sensors))
    _unique([s.id for s in sensors], f"{prefix}sensors", "id", "duplicates sensors[{first}]")
    modules: tuple[ModbusModule, ...] = ()
    if "modbus" in doc:
        mw = f"{prefix}modbus."
        mb = _mapping(doc["modbus"], mw)
        _check_keys(mb, {"modules"}, mw)
        raw_modules = mb.get("modules")
        if not isinstance(raw_modules, list) or not raw_modules:
            raise _fail(mw, "modules", raw_modules, "must be a non-empty list of modules")
        modules = tuple(_parse_module(m, f"{mw}modules[{i}].") for i, m in enumerate(raw_modules))
        names = _unique([m.name for m in modules], f"{mw}modules", "name", "duplicates modules[{first}]")
        _unique([(m.link_key, m.unit_id) for m in modules], f"{mw}modules", "unit_id",
                "is already used on the same connection by modules[{first}]", [m.unit_id for m in modules])
        for i, s in enumerate(sensors):
            if s.modbus is not None and s.modbus.module not in names:
                raise _fail(f"{prefix}sensors[{i}].modbus.", "module", s.modbus.module,
                            f"is not a module in modbus.modules {sorted(names)}")
    return SensorConfig(sensors=sensors, modules=modules,
                        max_age_s=_number(doc, "max_age_s", 60.0, prefix, positive=True),
                        source=source)


def load_sensor_config(path: str | pathlib.Path) -> SensorConfig:
    """Read and validate a sensor YAML file (or a cell file with such a section)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise SensorConfigError(f"{path}: no such sensor config file")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SensorConfigError(f"{path}: not valid YAML: {exc}") from None
    return parse_sensor_config(doc, source=str(path))


def require_modbus(config: SensorConfig) -> None:
    """Raise unless every sensor has a register and there is at least one module."""
    where = f"{config.source}: " if config.source else ""
    if not config.modules:
        raise SensorConfigError(f"{where}modbus.modules: missing (required by the modbus source)")
    for i, s in enumerate(config.sensors):
        if s.modbus is None:
            raise SensorConfigError(f"{where}sensors[{i}].modbus: missing for sensor {s.id!r} "
                                    "(required by the modbus source)")


def config_from_channels(channels: list[str], range_degc: tuple[float, float] = PLAUSIBLE_RANGE_DEGC,
                         max_age_s: float = 60.0) -> SensorConfig:
    """A default configuration with one uncalibrated sensor per channel (ids = channels)."""
    return SensorConfig(sensors=tuple(SensorSpec(id=c, channel=c, range_degc=range_degc)
                                      for c in channels), max_age_s=max_age_s)


SHIPPED_CONFIG_DIR = pathlib.Path(__file__).resolve().parent / "config"


def shipped_configs() -> list[str]:
    """Names of the sensor YAMLs shipped with the package (``<name>_sensors.yaml``)."""
    return sorted(p.name[: -len("_sensors.yaml")] for p in SHIPPED_CONFIG_DIR.glob("*_sensors.yaml"))


def resolve_sensor_config(name_or_path: str) -> pathlib.Path:
    """A path as given, or a shipped configuration by name (``nmv5000``, ``spindle_stand`` ...)."""
    p = pathlib.Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or "/" in name_or_path:
        return p
    shipped = SHIPPED_CONFIG_DIR / f"{name_or_path.replace('-', '_')}_sensors.yaml"
    if not shipped.is_file():
        raise SensorConfigError(f"sensor config {name_or_path!r}: neither a .yaml path nor a shipped "
                                f"configuration (shipped: {shipped_configs()})")
    return shipped
