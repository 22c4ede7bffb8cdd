"""Emulate Pt100/RTD Modbus modules on loopback, serving temperatures from a CSV or the twin.

It serves the modules and register map of a sensor YAML (the file the ``modbus`` source
reads), over Modbus TCP, RTU over TCP or a serial device, so a bench set-up or a test talks
real Modbus to it. The command is ``rtd_emulator_cli``. Transports and library use:
docs/sensors.md ("The RTD emulator").
"""
from __future__ import annotations

import asyncio
import functools
import threading
import time
from typing import Mapping

from pymodbus import FramerType
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from thermal_sensors.modbus_register_map import encode_temperature
from thermal_sensors.sensor_config import ModbusModule, SensorConfig, require_modbus

_FC_KIND = {3: "holding", 4: "input"}


class RtdEmulator:
    """A set of emulated RTD modules, served from a background thread's asyncio loop."""

    def __init__(self, config: SensorConfig):
        require_modbus(config)
        self.config = config
        # registers[(module name)][kind][address] = 16-bit word
        self._words: dict[str, dict[str, dict[int, int]]] = {
            m.name: {"input": {}, "holding": {}} for m in config.modules}
        self._silent: set[str] = set()
        self._lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._servers: list = []
        self.requests_served = 0

    # -- values ---------------------------------------------------------------------------
    def set_temperatures(self, values_degc: Mapping[str, float]) -> None:
        """Serve ``values_degc`` (sensor id -> raw degC; NaN = sensor fault)."""
        specs = {s.id: s for s in self.config.sensors}
        with self._lock:
            for sid, v in values_degc.items():
                if sid not in specs:
                    raise KeyError(f"set_temperatures: {sid!r} is not a configured sensor")
                reg = specs[sid].modbus
                self._words[reg.module][reg.register][reg.address] = encode_temperature(float(v), reg)

    def set_word(self, module: str, register: str, address: int, word: int) -> None:
        """Serve a raw register word (for tests of decoding)."""
        with self._lock:
            self._words[module][register][address] = int(word) & 0xFFFF

    def set_silent(self, module: str, silent: bool = True) -> None:
        """Make a module stop answering (its requests time out) or answer again."""
        self.config.module(module)  # KeyError for an unknown module
        with self._lock:
            (self._silent.add if silent else self._silent.discard)(module)

    # -- serving --------------------------------------------------------------------------
    async def _action(self, module: str, function_code: int, start_address: int, address: int,
                      count: int, registers: list[int], set_values):
        with self._lock:
            if module in self._silent:
                raise NoSuchIdException(f"module {module} is silent")  # server sends nothing
            words = self._words[module][_FC_KIND.get(function_code, "holding")]
            for k in range(count):
                registers[address - start_address + k] = words.get(address + k, 0)
            self.requests_served += 1
        return None

    def _devices(self, modules: list[ModbusModule]) -> list[SimDevice]:
        devices = []
        for m in modules:
            top = max([s.modbus.address for s in self.config.sensors
                       if s.modbus is not None and s.modbus.module == m.name] + [0])
            size = top + 16
            regs = [SimData(0, count=size, values=0, datatype=DataType.REGISTERS)]
            bits = [SimData(0, count=1, values=False, datatype=DataType.BITS)]
            devices.append(SimDevice(id=m.unit_id, simdata=(bits, bits, list(regs), list(regs)),
                                     action=functools.partial(self._action, m.name)))
        return devices

    async def _start_servers(self) -> None:
        groups: dict[tuple, list[ModbusModule]] = {}
        for m in self.config.modules:
            groups.setdefault(m.link_key, []).append(m)
        for modules in groups.values():
            m = modules[0]
            devices = self._devices(modules)
            if m.transport == "rtu" and not m.serial_port.startswith("socket://"):
                server = ModbusSerialServer(devices, framer=FramerType.RTU, port=m.serial_port,
                                            baudrate=m.baudrate, parity=m.parity, stopbits=m.stopbits,
                                            bytesize=m.bytesize, ignore_missing_devices=True)
            else:
                if m.transport == "rtu":
                    host, _, port = m.serial_port[len("socket://"):].rpartition(":")
                    address = (host or "127.0.0.1", int(port))
                else:
                    address = (m.host, m.port)
                framer = FramerType.SOCKET if m.transport == "tcp" else FramerType.RTU
                server = ModbusTcpServer(devices, framer=framer, address=address,
                                         ignore_missing_devices=True)
            await server.serve_forever(background=True)
            self._servers.append(server)

    def start(self, timeout_s: float = 10.0) -> None:
        """Open every endpoint; returns once all listen (raises if one cannot)."""
        if self._thread is not None:
            return
        ready = threading.Event()
        failure: list[BaseException] = []

        def run():
            loop = asyncio.new_event_loop()
            self._loop = loop
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(self._start_servers())
            except BaseException as exc:  # report to start(), then end the thread
                failure.append(exc)
                ready.set()
                loop.run_until_complete(self._shutdown_servers())
                loop.close()
                return
            ready.set()
            loop.run_forever()
            loop.run_until_complete(self._shutdown_servers())
            loop.close()

        self._thread = threading.Thread(target=run, name="rtd-emulator", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            raise RuntimeError(f"rtd emulator: endpoints not listening after {timeout_s} s")
        if failure:
            self._thread.join()
            self._thread = None
            raise RuntimeError(f"rtd emulator: cannot open an endpoint: {failure[0]}") from failure[0]

    async def _shutdown_servers(self) -> None:
        for server in self._servers:
            await server.shutdown()
        self._servers = []

    def stop(self) -> None:
        """Close every endpoint and drop the connections (the values are kept)."""
        if self._thread is None:
            return
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10.0)
        self._thread = None
        self._loop = None

    def __enter__(self) -> "RtdEmulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


# ------------------------------------------------------------------------------------------
def play_recording(emulator: RtdEmulator, recording, speed: float, loop: bool,
                   stop: threading.Event, progress=None) -> int:
    """Serve the recording's rows at their times (divided by ``speed``); rows served."""
    cols = {}
    for i, s in enumerate(emulator.config.sensors):
        if s.csv_column not in recording.columns:
            raise KeyError(f"sensors[{i}].channel: column {s.csv_column!r} is not in {recording.source} "
                           f"(temperature columns: {recording.names('sensor')})")
        cols[s.id] = recording.columns[s.csv_column]
    t = recording.time_s
    served = 0
    while True:
        t_wall0 = time.monotonic()
        for k in range(len(t)):
            due = t_wall0 + (t[k] - t[0]) / speed
            if stop.wait(max(0.0, due - time.monotonic())):
                return served
            emulator.set_temperatures({sid: float(c[k]) for sid, c in cols.items()})
            served += 1
            if progress is not None:
                progress(k, len(t))
        if not loop:
            return served
