"""The FL_THERMAL spindle programme as a twin scenario (``fl-thermal-programme``).

The programme is a fact of the FL_THERMAL recording, not of the twin: it lives here, with the
dataset's configuration, and reaches ``thermal-comp sim`` / ``make_timeline`` through the twin's
scenario plug-in group (``thermal_twin.sim.scenarios`` entry point in this package's setup.py).
:func:`programme_from_speed` reads a step programme off any recording's speed column; the
constant below is what it gives on the FL_THERMAL recording (also in its README), kept so the
scenario runs without the data file. No rclpy here.
"""
from __future__ import annotations

import numpy as np

from thermal_twin.sim.profiles import hall_ambient, step_programme
from thermal_twin.sim.scenarios import Scenario

#: The FL_THERMAL spindle programme (start s, 1/min): shared/data/fl_thermal/README.md, and
#: :func:`programme_from_speed` of the recording's ``spindle_rpm`` column (a test checks both agree).
FL_THERMAL_PROGRAMME = [(0, 0), (465, 1250), (14865, 0), (29265, 2500), (43665, 0), (58065, 3750),
                        (72465, 0), (86865, 5000), (101265, 0), (115665, 3500), (130065, 0),
                        (144465, 500), (151665, 1500), (158865, 2500), (162465, 4500), (166065, 0)]
FL_THERMAL_ROWS = 11115
FL_THERMAL_STEP_S = 15.0
H = 3600.0


class ProgrammeError(ValueError):
    """A speed column that gives no step programme; the message names the argument."""


def programme_from_speed(time_s, speed) -> list[tuple[float, float]]:
    """(start s, speed) at the first row and at every row where the speed changes."""
    t = np.asarray(time_s, dtype=float)
    s = np.asarray(speed, dtype=float)
    if t.ndim != 1 or t.shape != s.shape or t.size == 0:
        raise ProgrammeError(f"time_s / speed: shapes {t.shape} and {s.shape} must be equal and non-empty")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(s))):
        raise ProgrammeError("speed: the column has missing values; a step programme needs every row")
    changes = np.flatnonzero(np.diff(s) != 0) + 1
    return [(float(t[0]), float(s[0]))] + [(float(t[i]), float(s[i])) for i in changes]


def fl_thermal_programme(t, rng):
    """The spindle-stand inputs of the recording: its spindle programme and a hall at 26 degC."""
    amb = hall_ambient(t, rng, mean=26.0, day_amplitude=0.6, drift_per_day=0.3)
    return {"spindle_rpm": step_programme(t, FL_THERMAL_PROGRAMME), "ambient_degc": amb}


SCENARIO = Scenario("fl-thermal-programme", "the FL_THERMAL spindle programme (4 h run / 4 h rest blocks at "
                    "1250-5000 1/min, then mixed steps), 15 s steps, 46.3 h",
                    (FL_THERMAL_ROWS - 1) * FL_THERMAL_STEP_S / H, FL_THERMAL_STEP_S,
                    {"spindle_stand": fl_thermal_programme})
