"""Every reader and every message type fuzzed with hypothesis: bad input ends in the reader's
own error type with one line that names the place (key, line, byte), never in a crash or a
stray exception; a malformed config names its key."""
from __future__ import annotations

import copy
import pathlib
import shutil

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

REPO = pathlib.Path(__file__).resolve().parents[4]
FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

# ------------------------------------------------------------------ YAML documents
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12))
yaml_values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)), max_leaves=12)


def _paths(doc, prefix=()):
    """Every key path of a nested mapping/list document."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


def _mutate(doc, path, value):
    doc = copy.deepcopy(doc)
    if not path:
        return value
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return doc


def _one_line(msg: str) -> None:
    assert msg and "\n" not in msg.strip(), repr(msg)


def _valid_cell():
    return yaml.safe_load((REPO / "src/thermal_comp/test/platform/cells/two_nodes.yaml").read_text())


def _valid_sensors():
    return yaml.safe_load((REPO / "src/thermal_sensors/thermal_sensors/config/nmv5000_sensors.yaml").read_text())


def _valid_machine():
    return yaml.safe_load((REPO / "src/thermal_twin/thermal_twin/presets/nmv5000.yaml").read_text())


@pytest.mark.parametrize("which", ["cell", "sensors", "machine"])
@FUZZ
@given(data=st.data())
def test_a_mutated_config_is_accepted_or_refused_in_one_line(which, data):
    from thermal_comp.cell.config import CellConfigError, parse_cell
    from thermal_sensors.sensor_config import SensorConfigError, parse_sensor_config
    from thermal_twin.machine.schema import MachineSpecError, load_machine
    valid, parse, error = {
        "cell": (_valid_cell, lambda d: parse_cell(d, source="fuzz.yaml", resolve=False), CellConfigError),
        "sensors": (_valid_sensors, lambda d: parse_sensor_config(d, source="fuzz.yaml"), SensorConfigError),
        "machine": (_valid_machine, load_machine, MachineSpecError),
    }[which]
    doc = valid()
    path = data.draw(st.sampled_from(list(_paths(doc))), label="path")
    bad = _mutate(doc, path, data.draw(yaml_values, label="value"))
    try:
        parse(bad)
    except error as exc:
        _one_line(str(exc))


@pytest.mark.parametrize("which, key, value, names", [
    ("cell", ("nodes", 0, "restart"), {"max_restarts": -1}, "max_restarts"),
    ("cell", ("domain_id",), 999, "domain_id"),
    ("sensors", ("sensors", 0, "range_degc"), [50, -10], "range_degc"),
    ("sensors", ("max_age_s",), "soon", "max_age_s"),
])
def test_a_malformed_config_names_its_key(which, key, value, names):
    from thermal_comp.cell.config import CellConfigError, parse_cell
    from thermal_sensors.sensor_config import SensorConfigError, parse_sensor_config
    doc = _mutate(_valid_cell() if which == "cell" else _valid_sensors(), key, value)
    with pytest.raises((CellConfigError, SensorConfigError)) as err:
        parse_cell(doc, source="x.yaml", resolve=False) if which == "cell" else parse_sensor_config(doc, "x.yaml")
    _one_line(str(err.value))
    assert names in str(err.value)


# ------------------------------------------------------------------ the CSV reader
csv_cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.text(
    alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\n\x00"), max_size=6),
    st.just(""), st.just("nan"))


@FUZZ
@given(header=st.lists(st.sampled_from(["time_s", "ambient_c", "spindle_c", "E_X0C_um", "x", ""]),
                       min_size=0, max_size=5),
       rows=st.lists(st.lists(csv_cells, min_size=0, max_size=6), max_size=6))
def test_recording_csv_reader_refuses_garbage_with_a_line_number(tmp_path, header, rows):
    from thermal_comp_common.recording_csv import RecordingError, read_recording_csv
    p = tmp_path / "fuzz.csv"
    p.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")
    try:
        rec = read_recording_csv(p)
    except RecordingError as exc:
        _one_line(str(exc))
        assert str(p) in str(exc)
    else:
        t = np.asarray(rec.time_s, dtype=float)
        assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)   # accepted: times usable


# ------------------------------------------------------------------ the bag reader
@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    src = REPO / "bags" / "graph_swiss_lathe_random_speed_6h"
    if not src.is_dir():
        pytest.fail(f"{src} missing: the repository's recorded bags are part of the fixtures")
    return src


@settings(FUZZ, max_examples=30)
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(1, 255)), max_size=4))
def test_bag_reader_keeps_what_is_readable_and_reports_damage(tmp_path, small_bag, cut, flips):
    from thermal_comp_common.bags.reader import BagReadError, read_bag
    dst = tmp_path / "bag"
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(small_bag, dst)
    mcap = sorted(dst.glob("*.mcap"))[0]
    data = bytearray(mcap.read_bytes())
    for pos, x in flips:
        i = min(int(pos * len(data)), len(data) - 1)
        data[i] ^= x
    data = data[:max(1, int(cut * len(data)))] if cut < 1.0 else data
    mcap.write_bytes(bytes(data))
    try:
        c = read_bag(dst)
    except BagReadError as exc:
        _one_line(str(exc))
        return
    intact = cut >= 1.0 and not flips
    if intact:
        assert c.damage is None
    if c.damage is not None:
        _one_line(c.damage)
    times = [m.log_time_ns for m in c.messages]
    assert times == sorted(times)


# ------------------------------------------------------------------ every message type
def _message_classes():
    import thermal_comp_msgs.action as a
    import thermal_comp_msgs.msg as m
    import thermal_comp_msgs.srv as s
    out = [getattr(m, n) for n in ("AxisOffsets", "MachineState", "ModelStatus", "SimSync",
                                   "TemperatureArray", "ThermalErrors")]
    out += [s.TouchProbe.Request, s.TouchProbe.Response]
    out += [a.ProbeCycle.Goal, a.ProbeCycle.Result, a.ProbeCycle.Feedback]
    return out


@pytest.mark.parametrize("cls", _message_classes(), ids=lambda c: c.__name__)
@FUZZ
@given(blob=st.binary(max_size=200))
def test_random_bytes_never_crash_deserialization(cls, blob):
    from rclpy.serialization import deserialize_message, serialize_message
    try:
        msg = deserialize_message(blob, cls)
    except Exception as exc:   # rclpy raises for malformed CDR; the process must survive
        assert str(exc) or type(exc).__name__
        return
    # what was accepted serializes and reads back the same (repr: NaN-safe, padding-blind)
    assert repr(deserialize_message(serialize_message(msg), cls)) == repr(msg)


def _fill(cls, draw):
    """A message of ``cls`` with every field drawn from its declared type."""
    msg = cls()
    for name, typ in cls.get_fields_and_field_types().items():
        base = typ.split("<")[0]
        seq = "sequence" in typ or "[" in typ
        fixed = int(typ.split("[")[1].rstrip("]")) if "[" in typ and not typ.endswith("[]") else None
        elem = typ.split("<")[1].rstrip(">") if "<" in typ else base.split("[")[0]
        if elem in ("double", "float"):
            gen = st.floats(allow_nan=True, allow_infinity=True, width=64 if elem == "double" else 32)
        elif elem == "boolean":
            gen = st.booleans()
        elif elem in ("uint8", "octet"):
            gen = st.integers(0, 255)
        elif elem == "uint32":
            gen = st.integers(0, 2**32 - 1)
        elif elem == "int32":
            gen = st.integers(-2**31, 2**31 - 1)
        elif elem == "string":   # NUL ends a ROS string (C char*): see the test below
            gen = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                          max_size=8)
        else:
            continue   # nested types (header, time, ThermalErrors): left at their defaults
        if fixed is not None:
            setattr(msg, name, draw(st.lists(gen, min_size=fixed, max_size=fixed)))
        elif seq:
            setattr(msg, name, draw(st.lists(gen, max_size=5)))
        else:
            setattr(msg, name, draw(gen))
    return msg


@pytest.mark.parametrize("cls", _message_classes(), ids=lambda c: c.__name__)
@FUZZ
@given(data=st.data())
def test_every_field_value_round_trips(cls, data):
    from rclpy.serialization import deserialize_message, serialize_message
    msg = _fill(cls, data.draw)
    assert repr(deserialize_message(serialize_message(msg), cls)) == repr(msg)


def test_a_nul_character_ends_a_string_field():
    """ROS 2 strings are C strings: everything from a NUL on is dropped in transport (a sensor
    id 'amb\\x00ient' arrives as 'amb' and is then unknown to the consumer, never mixed up)."""
    from rclpy.serialization import deserialize_message, serialize_message
    from thermal_comp_msgs.msg import TemperatureArray
    msg = TemperatureArray(sensor_ids=["amb\x00ient", "ok"], temperatures_degc=[1.0, 2.0], status=[0, 0])
    back = deserialize_message(serialize_message(msg), TemperatureArray)
    assert list(back.sensor_ids) == ["amb", "ok"]
