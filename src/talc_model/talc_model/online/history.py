"""The run's history as the model node saw it, to warm a model started from another prior: every
instant it modelled (temperatures, machine state) and every probing cycle's end (the residual it
measured and the compensation applied then, or the failure), in order. A model fed this history
is where the running model would be had it started from that prior at the run's first instant
(errors and soft sensors count from there). Stored compactly (the key tuples are shared, values
as float tuples); bounded by ``max_instants``, beyond which it says it is incomplete and no swap
can be warmed from it. No rclpy.
"""
from __future__ import annotations

from typing import Mapping


class RunHistory:
    """Instants and probe outcomes since the run's first instant (module docstring)."""

    def __init__(self, max_instants: int = 100_000, complete: bool = True):
        self.max_instants = int(max_instants)
        self.events: list[tuple] = []
        self.instants = 0
        #: "" while the history holds the whole run; else why it does not
        self.incomplete = "" if complete else "the model resumed from a saved state: the run before it is not in memory"
        self._keys: dict[tuple, tuple] = {}

    def _intern(self, keys: tuple) -> tuple:
        return self._keys.setdefault(keys, keys)

    def instant(self, t_s: float, temperatures: Mapping[str, float], machine_state: Mapping[str, float]) -> None:
        """An instant the model modelled (a new one, not a repeat)."""
        if self.incomplete:
            return
        if self.instants >= self.max_instants:
            self.incomplete = f"the run is longer than the history kept ({self.max_instants} instants)"
            self.events.clear()
            return
        tk, mk = tuple(temperatures), tuple(machine_state)
        self.events.append(("i", float(t_s), self._intern(tk), tuple(float(temperatures[k]) for k in tk),
                            self._intern(mk), tuple(float(machine_state[k]) for k in mk)))
        self.instants += 1

    def probe(self, t_s: float, success: bool, measured: Mapping[str, float], applied: Mapping[str, float],
              reason: str = "") -> None:
        """A probing cycle ended: learned from (``success``) or failed (counted only)."""
        if self.incomplete:
            return
        if success:
            self.events.append(("p", float(t_s), dict(measured), {c: float(applied.get(c, 0.0)) for c in measured}))
        else:
            self.events.append(("f", float(t_s), reason))

    def restart(self) -> None:
        """The node started over with a fresh model at the run's first instant (nothing kept)."""
        self.events.clear()
        self.instants = 0
        self.incomplete = ""

    def __len__(self) -> int:
        return len(self.events)


def feed(model, event: tuple) -> None:
    """Give ``model`` one history event as the closed loop gave it to the running model: an
    instant's inputs and prediction, a probe's measurement, a failed cycle."""
    kind, t = event[0], event[1]
    if kind == "i":
        model.update_inputs(t, dict(zip(event[2], event[3])), dict(zip(event[4], event[5])))
        model.predict(t)
    elif kind == "p":
        model.add_measurement(t, event[2], event[3])
    else:
        model.add_failed_measurement(t, event[2])
