"""Register encoding of RTD module values and the grouping of registers into reads.

A Modbus register is 16 bits on the wire (0..65535). A module reports a temperature as
``raw * scale + offset_degc`` where raw is the register read as int16 (two's complement)
or uint16; a broken element (open or short circuit) is reported as a fault code
(by default the type's extreme, -32768 / 65535, as many RTD modules do).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from thermal_sensors.sensor_config import ModbusRegister, SensorConfig

MAX_REGISTERS_PER_READ = 125  # Modbus limit for function codes 3 and 4


def decode_register(word: int, reg: ModbusRegister) -> float:
    """Temperature in degC from one register word, NaN for the module's fault code."""
    if not 0 <= word <= 0xFFFF:
        raise ValueError(f"register word {word!r} outside 0..65535")
    raw = word - 0x10000 if (reg.signed and word >= 0x8000) else word
    if raw == reg.effective_fault_raw:
        return math.nan
    return raw * reg.scale + reg.offset_degc


def encode_temperature(value_degc: float, reg: ModbusRegister) -> int:
    """The register word a module would send for ``value_degc`` (what the emulator serves).

    Values beyond the type's span saturate one count inside it (so they never alias the
    fault code); NaN gives the fault code.
    """
    lo, hi = (-32768, 32767) if reg.signed else (0, 65535)
    if not math.isfinite(value_degc):
        raw = reg.effective_fault_raw
    else:
        raw = min(max(int(round((value_degc - reg.offset_degc) / reg.scale)), lo), hi)
        if raw == reg.effective_fault_raw:  # never alias the fault code: one count inside
            raw += 1 if raw < hi else -1
    return raw & 0xFFFF


@dataclass(frozen=True)
class RegisterRead:
    """One read request: ``count`` registers of ``register`` kind from ``start`` on a module.

    ``targets`` lists (sensor index, register offset within the read).
    """

    module: str
    register: str
    start: int
    count: int
    targets: tuple[tuple[int, int], ...]


def plan_reads(config: SensorConfig, max_gap: int = 8) -> list[RegisterRead]:
    """Group the sensors' registers into as few reads as possible per module and kind.

    Registers closer than ``max_gap`` are read together (reading a few unused registers
    is cheaper than another round trip); a read never exceeds 125 registers.
    """
    by_key: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for i, s in enumerate(config.sensors):
        if s.modbus is not None:
            by_key.setdefault((s.modbus.module, s.modbus.register), []).append((s.modbus.address, i))
    reads: list[RegisterRead] = []
    for (module, kind), entries in by_key.items():
        entries.sort()
        group: list[tuple[int, int]] = []
        for addr, i in entries:
            if group and (addr - group[-1][0] > max_gap or addr - group[0][0] >= MAX_REGISTERS_PER_READ):
                reads.append(_make_read(module, kind, group))
                group = []
            group.append((addr, i))
        if group:
            reads.append(_make_read(module, kind, group))
    return reads


def _make_read(module: str, kind: str, group: list[tuple[int, int]]) -> RegisterRead:
    start = group[0][0]
    return RegisterRead(module, kind, start, group[-1][0] - start + 1,
                        tuple((i, addr - start) for addr, i in group))
