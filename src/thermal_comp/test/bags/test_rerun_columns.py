"""Bag-to-rerun conversion in columns: the same scalars and text lines, at the same times, as
logging message by message; the .rrd of a bag (and the demo's) carries the view's blueprint."""
import collections
import subprocess
import sys

import rerun as rr

from bags_helpers import small_recording_csv
from test_rerun_view import RERUN, _env, _synthetic_messages
from thermal_comp.view.rerun_logging import TIMELINE, WALL_TIMELINE, RerunLogger, schematic_layout
from thermal_comp.view.run import bag_to_rrd
from thermal_comp_common.bags.csv_to_bag import csv_to_bag


class _Capture:
    """Stands in for a RecordingStream: every timed scalar and text row as (entity, sim time,
    value...) in ``rows`` (sim time None when the row is not on sim_time) and, for rows on
    wall_time, as (entity, wall time, value...) in ``walls``."""

    def __init__(self):
        self.t = self.wall = None
        self.rows = collections.Counter()
        self.walls = collections.Counter()

    def set_time(self, timeline, duration=None, timestamp=None):
        if timeline == TIMELINE:
            self.t = round(duration, 9)
        else:
            assert timeline == WALL_TIMELINE, timeline
            self.wall = round(timestamp, 9)

    def disable_timeline(self, timeline):
        if timeline == TIMELINE:
            self.t = None
        else:
            self.wall = None

    def _row(self, path, t, wall, *values):
        self.rows[(path, t, *values)] += 1
        if wall is not None:
            self.walls[(path, wall, *values)] += 1

    def log(self, path, entity, static=False):
        if static:
            return
        if isinstance(entity, rr.Scalars):
            self._row(path, self.t, self.wall, entity.scalars.as_arrow_array().to_pylist()[0])
        elif isinstance(entity, rr.TextLog):
            self._row(path, self.t, self.wall, entity.text.as_arrow_array().to_pylist()[0],
                      entity.level.as_arrow_array().to_pylist()[0])

    def send_columns(self, path, indexes, columns):
        if path.endswith("machine/sensors"):         # the 3D layout: not a scalar or text row
            return
        times = {i.timeline_name(): [round(v * 1e-9, 9) for v in i.as_arrow_array().cast("int64").to_pylist()]
                 for i in indexes}
        values = [c.as_arrow_array().to_pylist() for c in columns]
        n = len(values[0])
        sim, wall = times.get(TIMELINE, [None] * n), times.get(WALL_TIMELINE, [None] * n)
        for i in range(n):
            self._row(path, sim[i], wall[i], *(v[i][0] for v in values))


def _logged(columnar: bool) -> collections.Counter:
    rec = _Capture()
    logger = RerunLogger(rec, schematic_layout(["a"]), columnar=columnar)
    for topic, type_name, t, msg in _synthetic_messages():
        logger.log(topic, type_name, msg, int(t * 1e9))
    assert (logger.send_columns() > 0) == columnar
    return rec.rows


def test_columns_hold_what_message_by_message_logging_holds():
    by_message, by_column = _logged(False), _logged(True)
    assert by_message and by_column == by_message
    assert any(k[0] == "cell1/events" for k in by_column)          # text lines too
    assert ("cell1/errors/E_X0C/predicted", 240.0, 5.0) in by_column


def test_a_converted_bag_opens_with_the_blueprint(tmp_path):
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=30), tmp_path / "bag")
    n, damage = bag_to_rrd(tmp_path / "bag", tmp_path / "out.rrd")
    assert (n, damage) == (90, None)
    printed = subprocess.run([str(RERUN), "rrd", "print", str(tmp_path / "out.rrd")], env=_env(tmp_path),
                             capture_output=True, text=True, timeout=120).stdout
    assert "ViewportBlueprint" in printed                 # the blueprint store is in the file
    assert "with 30 rows" in printed and "/temperatures/ambient" in printed   # one chunk per entity
