"""The ``modbus`` source: RTD modules over Modbus TCP, RTU (serial) or RTU over TCP.

All Modbus I/O runs off the ROS executor: one poller thread per connection ("link": a
TCP endpoint or an RS-485 line; several modules/unit ids may share it). Every read has
a timeout (the largest ``timeout_s`` of the link's modules); a module that does not
answer, answers with an exception or sends a fault code marks its sensors FAILED, the
others keep going. Failed connections and failed modules are retried with exponential
back-off from ``reconnect_min_s`` to ``reconnect_max_s``; after a failed read a TCP
connection is re-opened so that a late answer can never be taken for a new one (a serial
line stays open: pymodbus flushes its input before each request).

:meth:`ModbusSource.sample` never blocks: it returns the newest readings with their
age, and the status rules turn readings older than ``max_age_s`` into FAILED.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from thermal_sensors.modbus_register_map import RegisterRead, decode_register, plan_reads
from thermal_sensors.sensor_config import ModbusModule, SensorConfig, require_modbus
from thermal_sensors.temperature_source import RawSample


@dataclass
class _Backoff:
    min_s: float
    max_s: float
    delay_s: float = 0.0
    next_try: float = -np.inf

    def ready(self, now: float) -> bool:
        return now >= self.next_try

    def failed(self, now: float) -> float:
        self.delay_s = self.min_s if self.delay_s == 0.0 else min(2.0 * self.delay_s, self.max_s)
        self.next_try = now + self.delay_s
        return self.delay_s

    def succeeded(self) -> None:
        self.delay_s, self.next_try = 0.0, -np.inf


class _ReadingStore:
    """Newest readings of all sensors, shared by the poller threads (lock-protected)."""

    def __init__(self, n: int):
        self.lock = threading.Lock()
        self.values = np.full(n, np.nan)
        self.ok = np.zeros(n, bool)
        self.acquired = np.full(n, -np.inf)   # monotonic seconds
        self.reasons = ["not read yet"] * n

    def put_ok(self, i: int, value: float, when: float) -> None:
        self.values[i], self.ok[i], self.acquired[i], self.reasons[i] = value, True, when, ""

    def put_failed(self, i: int, reason: str) -> None:
        self.values[i], self.ok[i], self.reasons[i] = np.nan, False, reason


class ModbusLink:
    """One connection and the modules behind it; :meth:`poll_once` reads each module once."""

    def __init__(self, modules: list[ModbusModule], reads: list[RegisterRead], config: SensorConfig,
                 store: _ReadingStore, clock: Callable[[], float]):
        self.modules = {m.name: m for m in modules}
        first = modules[0]
        self.transport = first.transport
        self.description = (f"{first.transport}://{first.serial_port}" if first.transport == "rtu"
                            else f"{first.transport}://{first.host}:{first.port}")
        self.timeout_s = max(m.timeout_s for m in modules)
        self.poll_period_s = min(m.poll_period_s for m in modules)
        self.reads = reads
        self.config = config
        self.store = store
        self.clock = clock
        self.client = None
        self.link_backoff = _Backoff(first.reconnect_min_s, first.reconnect_max_s)
        self.module_backoff = {m.name: _Backoff(m.reconnect_min_s, m.reconnect_max_s) for m in modules}
        self.connects = 0

    def _new_client(self):
        m = next(iter(self.modules.values()))
        if m.transport == "rtu":
            return ModbusSerialClient(m.serial_port, framer=FramerType.RTU, baudrate=m.baudrate,
                                      parity=m.parity, stopbits=m.stopbits, bytesize=m.bytesize,
                                      timeout=self.timeout_s, retries=0)
        framer = FramerType.RTU if m.transport == "rtu_over_tcp" else FramerType.SOCKET
        return ModbusTcpClient(m.host, port=m.port, framer=framer, timeout=self.timeout_s, retries=0)

    def close(self) -> None:
        if self.client is not None:
            try:
                self.client.close()
            finally:
                self.client = None

    def _fail_module(self, name: str, reason: str) -> None:
        with self.store.lock:
            for r in self.reads:
                if r.module == name:
                    for i, _ in r.targets:
                        self.store.put_failed(i, reason)

    def _ensure_connected(self) -> str:
        """'' when connected, else why not (and the link backs off)."""
        now = self.clock()
        if self.client is not None and self.client.connected:
            return ""
        if not self.link_backoff.ready(now):
            return (f"{self.description}: not connected, next attempt in "
                    f"{self.link_backoff.next_try - now:.2g} s")
        self.close()
        self.client = self._new_client()
        try:
            ok = self.client.connect()
        except Exception as exc:  # pyserial raises on a missing device
            ok, why = False, str(exc)
        else:
            why = "connection refused or no route"
        if not ok:
            self.close()
            delay = self.link_backoff.failed(now)
            return f"{self.description}: cannot connect ({why}); retry in {delay:.2g} s"
        self.link_backoff.succeeded()
        self.connects += 1
        return ""

    def poll_once(self) -> None:
        """Read every module of the link once (modules in back-off are skipped)."""
        for name, module in self.modules.items():
            backoff = self.module_backoff[name]
            now = self.clock()
            if not backoff.ready(now):
                continue  # its sensors keep the FAILED status of the last attempt
            why = self._ensure_connected()
            if why:
                self._fail_module(name, why)
                continue
            for r in (r for r in self.reads if r.module == name):
                why = self._read(module, r)
                if why:
                    delay = backoff.failed(self.clock())
                    self._fail_module(name, f"{why}; retry in {delay:.2g} s")
                    if self.transport != "rtu" or not self.client.connected:
                        # TCP: drop any late answer with the connection. A serial line stays
                        # open (re-opening costs, pymodbus flushes its input before a send).
                        self.close()
                    break
            else:
                backoff.succeeded()

    def _read(self, module: ModbusModule, r: RegisterRead) -> str:
        fn = (self.client.read_input_registers if r.register == "input"
              else self.client.read_holding_registers)
        try:
            rr = fn(r.start, count=r.count, device_id=module.unit_id)
        except ModbusException as exc:
            return f"module {module.name!r} (unit {module.unit_id}) did not answer: {exc}"
        except OSError as exc:
            return f"module {module.name!r} (unit {module.unit_id}): I/O error {exc}"
        if rr.isError():
            return f"module {module.name!r} (unit {module.unit_id}) answered with an exception: {rr}"
        words = rr.registers
        if len(words) < r.count:
            return (f"module {module.name!r} (unit {module.unit_id}) sent {len(words)} registers, "
                    f"asked for {r.count}")
        when = self.clock()
        with self.store.lock:
            for i, off in r.targets:
                reg = self.config.sensors[i].modbus
                value = decode_register(words[off], reg)
                if np.isnan(value):
                    self.store.put_failed(i, f"module {module.name!r} reports a sensor fault at "
                                             f"{r.register} register {r.start + off}")
                else:
                    self.store.put_ok(i, value, when)
        return ""


class ModbusSource:
    """Raw readings of all configured sensors from their Modbus modules."""

    def __init__(self, config: SensorConfig, clock: Callable[[], float] = time.monotonic):
        require_modbus(config)
        self.config = config
        self.sensor_ids = config.sensor_ids
        self.clock = clock
        self.store = _ReadingStore(len(config.sensors))
        reads = plan_reads(config)
        groups: dict[tuple, list[ModbusModule]] = {}
        for m in config.modules:
            groups.setdefault(m.link_key, []).append(m)
        self.links = []
        for modules in groups.values():
            names = {m.name for m in modules}
            self.links.append(ModbusLink(modules, [r for r in reads if r.module in names],
                                         config, self.store, clock))
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # -- polling ------------------------------------------------------------------------
    def poll_once(self) -> None:
        """Read every module once, in the calling thread (tests, one-shot tools)."""
        if self._threads:
            raise RuntimeError("poll_once() while the poller threads run")
        for link in self.links:
            link.poll_once()

    def start(self) -> None:
        """Start one poller thread per link (reads every ``poll_period_s``)."""
        if self._threads:
            return
        self._stop.clear()
        for k, link in enumerate(self.links):
            t = threading.Thread(target=self._run, args=(link,), name=f"modbus-link-{k}", daemon=True)
            t.start()
            self._threads.append(t)

    def _run(self, link: ModbusLink) -> None:
        next_poll = self.clock()
        while not self._stop.is_set():
            try:
                link.poll_once()
            except Exception as exc:  # never let a poller die silently: fail its sensors
                for name in link.modules:
                    link._fail_module(name, f"poller error: {exc!r}")
                link.close()
            next_poll += link.poll_period_s
            now = self.clock()
            if next_poll < now:  # a slow cycle (timeouts): do not try to catch up
                next_poll = now
            self._stop.wait(max(0.0, next_poll - now))
        link.close()

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=max(l.timeout_s for l in self.links) + 2.0)
        self._threads = []
        for link in self.links:
            link.close()

    # -- the source interface ------------------------------------------------------------
    def sample(self, t_s: float) -> RawSample:
        now = self.clock()
        with self.store.lock:
            age = now - self.store.acquired
            return RawSample(t_s, self.store.values.copy(), self.store.ok.copy(),
                             t_s - age, list(self.store.reasons))
