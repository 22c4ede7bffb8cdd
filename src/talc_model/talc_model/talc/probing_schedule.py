"""When TALC probes (Blaser thesis ch. 6 and the choices of docs/talc.md): the regular interval of
each phase, a probing after a switch of a ``switch_probe_input`` signal, and the model's own
change-probing rule (:mod:`talc_model.probing.change_probing`). A mixin of :class:`talc_model.talc.model.TalcModel`,
which owns the state it reads (phase, grid, last probing, configuration). No rclpy here.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from talc_model.adaptive_model import PHASE_CALIBRATION, PHASE_COMPENSATION, PHASE_NO_GOOD
from talc_model.probing.change_probing import change_probe_due


class TalcProbingSchedule:
    """The probing schedule of :class:`talc_model.talc.model.TalcModel`."""

    def _watch_switch(self, t_s: float, signals: Mapping[str, float]) -> None:
        """A switch of a ``switch_probe_input`` signal makes one probing due ``switch_probe_delay_min``
        later (a switch while one is pending is ignored; an unknown value keeps the last)."""
        for name in self.config.switch_probe_names:
            v = signals.get(name)
            try:
                v = float(v) if v is not None else math.nan
            except (TypeError, ValueError):
                raise ValueError(f"update_inputs: switch_probe_input '{name}': value {v!r} is not a number") from None
            if not math.isfinite(v):
                continue
            last = self.switch_last.get(name)
            if last is not None and abs(v - last) > 0.5 and self.switch_probe_due_s is None:
                self.switch_probe_due_s = t_s + 60.0 * self.config.switch_probe_delay_min
                self.events.append({"t_s": t_s, "event": "switch", "input": name, "value": v})
            self.switch_last[name] = v

    def _interval_s(self) -> float:
        c = self.config
        if self.phase == PHASE_CALIBRATION:
            return c.cp_interval_s
        if self.phase == PHASE_NO_GOOD:
            return c.ng_interval_min * 60.0
        return c.post_cp_interval_h * 3600.0

    def next_probe_due_s(self) -> float:
        if self.last_probe_t is None:
            return self.t0 if self.t0 is not None else -math.inf
        gap = self._interval_s()
        if self.config.interval_from_cycle_end:
            gap += self.config.probe_duration_s
        due = self.last_probe_t + gap
        return due if self.switch_probe_due_s is None else min(due, self.switch_probe_due_s)

    def _probed(self, t_s: float) -> None:
        """A probing (done or failed) at t_s: it is the pending switch probing once that is due."""
        self.last_probe_t = t_s
        if self.switch_probe_due_s is not None and t_s + 1e-9 >= self.switch_probe_due_s:
            self.switch_probe_due_s = None

    def probe_due(self, t_s: float) -> bool:
        self._advance(float(t_s))
        return float(t_s) >= self.next_probe_due_s() - 1e-9 or self._change_due(float(t_s))

    def _in_check(self) -> bool:
        """In a prior's check phase (TalcPriorModel); plain TALC has none."""
        return False

    def _check_end_s(self) -> float:
        """When a prior's check phase ends (TalcPriorModel); plain TALC: at the start. The
        change-probing budget counts from here (the check phase's probings are not charged)."""
        return self.t0

    def _change_due(self, t_s: float) -> bool:
        """The model's own probing rule (TalcConfig.change_probe_threshold): its predicted change
        of some component since the last probing exceeds the threshold times its probe noise,
        while Q_prod over the last 24 h with this probing stays at or above ``change_probe_min_q_prod_pct``."""
        c = self.config
        threshold = c.change_probe_threshold if self.change_thresholds is None else self.change_thresholds
        if not np.any(np.isfinite(threshold)) or self.phase != PHASE_COMPENSATION or \
                self.last_probe_t is None or self._in_check() or self.grid is None or \
                t_s - self.last_probe_t < 60.0 * c.change_probe_min_interval_min:
            return False
        g = self.grid
        noise = np.sqrt([self._probe_noise_var(n) for n in self.component_names])
        return change_probe_due(g.x[: g.n], g.measured[: g.n], int(round((self.last_probe_t - self.t0) / self.step)),
                                t_s, self.t0, self.step, noise, threshold, c.probe_duration_s,
                                c.change_probe_min_q_prod_pct, self._check_end_s())
