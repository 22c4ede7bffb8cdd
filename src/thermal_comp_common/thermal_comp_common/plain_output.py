"""Output of long work that reads right on a terminal and in a log file.

On a terminal, :func:`progress` is a tqdm bar and :func:`console` rich's own console. When the
output is not a terminal (piped, redirected, a CI log), :func:`progress` writes one complete
line per tenth of the work and one at the end (no carriage-return frames), and
:func:`console` never breaks a text line (tables get a wide fixed width instead of 80).
"""
from __future__ import annotations

import math
import sys
import time
from typing import TextIO

from rich.console import Console
from tqdm import tqdm

#: Columns for tables when the output is not a terminal (a table is never soft-wrapped).
PLAIN_WIDTH = 200


def _is_terminal(stream) -> bool:
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class Progress:
    """Progress of ``total`` units of work: ``advance(n)``, ``to(value)``, ``close()``."""

    def __init__(self, total: float, desc: str, unit: str, file: TextIO | None = None,
                 steps: int = 10, decimals: int = 0, terminal: bool | None = None):
        if not (isinstance(total, (int, float)) and math.isfinite(total) and total >= 0):
            raise ValueError(f"progress total: expected a finite number >= 0, got {total!r}")
        self.file = sys.stderr if file is None else file
        self.total, self.desc, self.unit = total, desc, unit
        self.n = 0.0
        self._steps, self._decimals = max(int(steps), 1), decimals
        self._printed = 0         # tenths (steps) already written as lines
        self._t0 = time.monotonic()
        self._closed = False
        tty = _is_terminal(self.file) if terminal is None else terminal
        self._bar = tqdm(total=total, desc=desc, unit=unit, leave=False, file=self.file) if tty else None

    def advance(self, n: float = 1) -> None:
        self.to(self.n + n)

    def to(self, value: float) -> None:
        """Set the work done so far to ``value`` (never beyond ``total``)."""
        self.n = min(float(value), float(self.total))
        if self._bar is not None:
            self._bar.n = round(self.n, self._decimals) if self._decimals else int(self.n)
            self._bar.refresh()
            return
        step = self._steps if self.total == 0 else math.floor(self.n / self.total * self._steps + 1e-9)
        if step > self._printed and step < self._steps:
            self._printed = step
            self._line()

    def close(self) -> None:
        """The last line (plain output) or the bar removed (terminal); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        else:
            self._line(done=True)

    def _line(self, done: bool = False) -> None:
        pct = 100.0 if self.total == 0 else 100.0 * self.n / self.total
        n = f"{self.n:.{self._decimals}f}"
        total = f"{self.total:.{self._decimals}f}"
        state = ("done" if self.n >= self.total else "stopped") if done else "elapsed"
        print(f"{self.desc}: {n}/{total} {self.unit} ({pct:.0f} %), {state} "
              f"{time.monotonic() - self._t0:.0f} s", file=self.file, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def progress(total: float, desc: str, unit: str, file: TextIO | None = None, **kwargs) -> Progress:
    """A :class:`Progress` on ``file`` (default stderr): a bar on a terminal, else plain lines."""
    return Progress(total, desc, unit, file=file, **kwargs)


def console(file: TextIO | None = None, min_width: int | None = None) -> Console:
    """rich's console on a terminal (at least ``min_width`` columns for wide tables); otherwise one
    that writes each text line whole (``soft_wrap``) and lays tables out on :data:`PLAIN_WIDTH`
    columns (or ``min_width``)."""
    c = Console(file=file)
    if c.is_terminal:
        return c if min_width is None else Console(file=file, width=max(min_width, c.width))
    return Console(file=file, width=max(PLAIN_WIDTH, min_width or 0), soft_wrap=True)
