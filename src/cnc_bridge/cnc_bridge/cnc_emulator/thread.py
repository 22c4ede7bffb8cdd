"""The CNC emulator in its own thread and event loop, driven from synchronous code (tests, demo)."""
from __future__ import annotations

import os
from typing import Callable, Mapping

from cnc_bridge.cnc_emulator.probe import ProbeMove
from cnc_bridge.cnc_emulator.server import CncEmulator, EmulatorConfig, EmulatorState
from cnc_bridge.loop_thread import LoopThread


#: s: the emulator's start-up deadline on an idle machine (see startup_deadline_s)
STARTUP_BASE_S = 20.0


def startup_deadline_s(base_s: float = STARTUP_BASE_S) -> float:
    """``base_s`` x max(1, 1-minute load average / CPU count): start-up builds asyncua's standard
    address space, CPU-bound work that a loaded machine stretches by about that factor."""
    try:
        load = os.getloadavg()[0]
    except OSError:        # no load average on this platform: the idle deadline
        load = 0.0
    return base_s * max(1.0, load / (os.cpu_count() or 1))


class CncEmulatorThread:
    """:class:`CncEmulator` in its own thread and event loop, driven from synchronous code.

    ``restart(keep_state=False)`` emulates a CNC whose compensation was reset to zero,
    ``restart(state=...)`` one that came back holding something else.
    """

    def __init__(self, config: EmulatorConfig, probe_move: ProbeMove | None = None,
                 on_compensation: Callable[[dict[str, float]], None] | None = None):
        self.config = config
        self._probe_move = probe_move
        self._on_comp = on_compensation
        self._io = LoopThread("cnc-emulator")
        self.emulator: CncEmulator | None = None
        self.write_log: list[tuple[str, float]] = []   # accumulated over restarts
        self.moves: list[tuple[str, float, float]] = []  # CncEmulator.moves, over restarts

    def _run(self, coro, timeout: float = 20.0):
        return self._io.run(coro, timeout)

    def start(self, state: EmulatorState | None = None) -> "CncEmulatorThread":
        self.emulator = CncEmulator(self.config, self._probe_move, self._on_comp, state)
        self.emulator.write_log = self.write_log
        self.emulator.moves = self.moves
        deadline = startup_deadline_s()
        try:
            self._run(self.emulator.start(), deadline)
        except TimeoutError:
            raise TimeoutError(f"CNC emulator on {self.config.endpoint}: not listening within {deadline:.0f} s "
                               f"({STARTUP_BASE_S:g} s scaled by the machine's load)") from None
        return self

    def stop(self) -> None:
        if self.emulator is not None:
            self._run(self.emulator.stop())

    def restart(self, keep_state: bool = True, state: EmulatorState | None = None) -> None:
        """Stop and start again: with its state, reset (``keep_state`` False) or holding ``state``."""
        if state is None and keep_state:
            state = self.emulator.state
        self.stop()
        self.start(state)

    def close(self) -> None:
        self.stop()
        self._io.stop()

    def applied_um(self) -> dict[str, float]:
        return self._run(_call(self.emulator.applied_um))

    def set_position(self, axis: str, value: float) -> None:
        self._run(self.emulator.set_position(axis, value))

    def set_positions(self, positions: Mapping[str, float]) -> None:
        """Move several axes in one hop to the emulator's loop."""
        async def move():
            for axis, value in positions.items():
                await self.emulator.set_position(axis, value)
        self._run(move())

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


async def _call(fn):
    return fn()
