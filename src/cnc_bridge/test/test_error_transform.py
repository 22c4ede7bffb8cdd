"""Eq. 6.3-6.5 against hand-computed cases (as printed and the rigid-body convention), the
rigid convention against the twin's probing geometry, and the lathe's per-tool offsets."""
import math

import numpy as np
import pytest

from cnc_bridge.error_transform import (FIVE_AXIS_COMPONENTS, HtmGeometry, LatheToolOffsets,
                                        ToolOffsetModel, TransformInputError, fit_tool_offset_model,
                                        five_axis_offsets_um, offsets_from_errors)
from thermal_comp_common.kinematics import applied_offsets_in_component_space

POS = dict(x_mm=100.0, y_mm=200.0, z_mm=300.0)   # mm; sphere radius d/2 = 160 mm
C30, S30 = math.cos(math.radians(30)), 0.5


def only(name, value):
    e = {c: 0.0 for c in FIVE_AXIS_COMPONENTS}
    e[name] = value
    return e


# (component, value, B [deg], expected X, Y, Z in um), each worked out by hand from eq. 6.3-6.5:
# um/m * mm * 1e-3 = um; E_R0T scales with pos / 160 mm.
CASES = [
    ("E_X0C", 10.0, 0.0, (10.0, 0.0, 0.0)),
    ("E_X0C", 10.0, 90.0, (0.0, 0.0, -10.0)),
    ("E_X0C", 10.0, 30.0, (10 * C30, 0.0, -5.0)),
    ("E_Y0C", 10.0, 0.0, (0.0, 10.0, 0.0)),
    ("E_Y0C", 10.0, 90.0, (0.0, 10.0, 0.0)),
    ("E_Y0C", 10.0, 30.0, (0.0, 10.0, 0.0)),
    ("E_Z0T", 10.0, 0.0, (0.0, 0.0, 10.0)),
    ("E_Z0T", 10.0, 90.0, (10.0, 0.0, 0.0)),
    ("E_Z0T", 10.0, 30.0, (5.0, 0.0, 10 * C30)),
    ("E_R0T", 16.0, 0.0, (10.0, 20.0, 0.0)),          # 16*100/160, 16*200/160
    ("E_R0T", 16.0, 90.0, (0.0, 20.0, 30.0)),         # Z: 16*300/160
    ("E_R0T", 16.0, 30.0, (10 * C30, 20.0, 15.0)),
    ("E_A0C", 10.0, 0.0, (0.0, 3.0, 2.0)),            # Y: 10*0.3, Z: 10*0.2
    ("E_A0C", 10.0, 90.0, (2.0, -1.0, 0.0)),          # X: 10*0.2, Y: -10*0.1
    ("E_A0C", 10.0, 30.0, (1.0, 3 * C30 - 0.5, 2 * C30)),
    ("E_B0C", 10.0, 0.0, (3.0, 0.0, -1.0)),           # X: 10*0.3, Z: -10*0.1
    ("E_B0C", 10.0, 90.0, (3.0, 0.0, -1.0)),
    ("E_B0C", 10.0, 30.0, (3.0, 0.0, -1.0)),
    ("E_C0C", 10.0, 0.0, (-2.0, 1.0, 0.0)),           # X: -10*0.2, Y: 10*0.1
    ("E_C0C", 10.0, 90.0, (0.0, -3.0, 2.0)),          # Y: -10*0.3, Z: 10*0.2
    ("E_C0C", 10.0, 30.0, (-2 * C30, C30 - 1.5, 1.0)),
]


@pytest.mark.parametrize("name,value,b_deg,expected", CASES)
def test_each_error_alone_as_printed(name, value, b_deg, expected):
    off = five_axis_offsets_um(only(name, value), b_deg=b_deg, convention="printed", **POS)
    assert (off["X"], off["Y"], off["Z"]) == pytest.approx(expected, abs=1e-12)


X30 = 100 * C30 - 300 * S30          # table-frame x of the point at B = 30 deg, mm
# (table frame p_t = R_y(B)^T p: x_t = X cos B - Z sin B, z_t = X sin B + Z cos B)
# The rigid convention differs from the printed one only where the docstring says: the
# E_C0C sense (C' table, eq. 5.10), the E_A0C*Z sign in Y, and E_R0T/E_A0C off 0/90 deg.
RIGID_DIFFERENT = [
    ("E_C0C", 10.0, 0.0, (2.0, -1.0, 0.0)),           # X: +10*0.2, Y: -10*0.1
    ("E_C0C", 10.0, 90.0, (0.0, 3.0, -2.0)),          # Y: +10*0.3, Z: -10*0.2
    ("E_A0C", 10.0, 0.0, (0.0, -3.0, 2.0)),           # Y: -10*0.3 (rigid tilt about +X)
    ("E_A0C", 10.0, 90.0, (2.0, -1.0, 0.0)),          # same as printed at 90 deg
    ("E_R0T", 16.0, 30.0, (0.1 * X30 * C30, 20.0, -0.1 * X30 * S30)),
    ("E_A0C", 10.0, 30.0, (10 * 0.2 * S30, -10 * (100 * S30 + 300 * C30) * 1e-3, 10 * 0.2 * C30)),
]
RIGID_SAME = [c for c in CASES if c[0] not in ("E_C0C",) and not (c[0] in ("E_A0C", "E_R0T") and c[2] == 30.0)
              and not (c[0] == "E_A0C" and c[2] == 0.0)]


@pytest.mark.parametrize("name,value,b_deg,expected", RIGID_DIFFERENT + RIGID_SAME)
def test_each_error_alone_rigid(name, value, b_deg, expected):
    off = five_axis_offsets_um(only(name, value), b_deg=b_deg, **POS)
    assert (off["X"], off["Y"], off["Z"]) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("b_deg", [0.0, 90.0, 30.0, -45.0])
@pytest.mark.parametrize("name", FIVE_AXIS_COMPONENTS)
def test_rigid_offsets_cancel_what_the_twins_probe_sees(name, b_deg):
    """Offsets at the sphere centre, with the origin where the errors are defined, cancel
    the sphere's displacement in the twin's probing model at every C indexing."""
    from thermal_twin.machine.artefact_geometry import DEFAULT_GEOMETRY, true_sphere_centre
    s = DEFAULT_GEOMETRY.sphere
    geometry = HtmGeometry(origin_mm=(*s.c_axis_xy_mm, s.centre_z_mm),
                           b_pivot_xz_mm=(s.c_axis_xy_mm[0], s.b_pivot_z_mm))
    errors = only(name, 10.0)
    for c_deg in (0.0, 90.0, 180.0, 270.0):
        nominal = true_sphere_centre(c_deg, b_deg, {}, {})
        x, y, z = nominal
        off = offsets_from_errors(errors, {"X": x, "Y": y, "Z": z, "B": b_deg}, geometry=geometry)
        seen = true_sphere_centre(c_deg, b_deg, errors, off)      # true minus applied
        # cancelled to first order; what is left is second order in the errors (< 0.1 nm)
        assert np.abs(seen - nominal).max() * 1000.0 < 1e-4, (c_deg, off)


def test_all_errors_superpose_at_an_arbitrary_angle():
    values = dict(E_X0C=3.0, E_Y0C=-7.0, E_Z0T=12.0, E_R0T=4.0, E_A0C=-15.0, E_B0C=6.0, E_C0C=9.0)
    b = 37.5
    for convention in ("printed", "rigid"):
        total = five_axis_offsets_um(values, b_deg=b, convention=convention, **POS)
        parts = [five_axis_offsets_um(only(n, v), b_deg=b, convention=convention, **POS)
                 for n, v in values.items()]
        for axis in "XYZ":
            assert total[axis] == pytest.approx(sum(p[axis] for p in parts), abs=1e-12)


def test_at_the_origin_only_the_table_position_errors_remain():
    values = dict(E_X0C=3.0, E_Y0C=-7.0, E_Z0T=12.0, E_R0T=4.0, E_A0C=-15.0, E_B0C=6.0, E_C0C=9.0)
    for convention in ("printed", "rigid"):
        off = five_axis_offsets_um(values, 0.0, 0.0, 0.0, 0.0, convention=convention)
        assert (off["X"], off["Y"], off["Z"]) == pytest.approx((3.0, -7.0, 12.0))


def test_missing_or_bad_input_names_the_field():
    e = only("E_X0C", 1.0)
    del e["E_C0C"]
    with pytest.raises(TransformInputError, match="E_C0C"):
        five_axis_offsets_um(e, 0, 0, 0, 0)
    with pytest.raises(TransformInputError, match="'E_Y0C'.*nan"):
        five_axis_offsets_um(only("E_Y0C", float("nan")), 0, 0, 0, 0)
    with pytest.raises(TransformInputError, match="convention"):
        five_axis_offsets_um(only("E_Y0C", 1.0), 0, 0, 0, 0, convention="thesis")
    with pytest.raises(TransformInputError, match="axis position 'Z'"):
        offsets_from_errors(only("E_Y0C", 1.0), {"X": 0.0, "Y": 0.0})


def test_machine_without_b_axis_uses_b_zero():
    off = offsets_from_errors(only("E_Z0T", 5.0), {"X": 1.0, "Y": 2.0, "Z": 3.0})
    assert off == pytest.approx({"X": 0.0, "Y": 0.0, "Z": 5.0})


def test_lathe_tool_offsets_from_tls_prediction_and_offset_models():
    lathe = LatheToolOffsets("GB_X", {"T01_X": ToolOffsetModel(2.0, 0.5),
                                      "T02_X": ToolOffsetModel(-1.0, 0.0)})
    off = offsets_from_errors({"GB_X": 8.0}, {}, lathe=lathe)
    assert off == pytest.approx({"GB_X": 8.0, "T01_X": 8.0 + 2.0 + 4.0, "T02_X": 7.0})
    # a tool component predicted by the model itself wins over the bridge's offset model
    off = offsets_from_errors({"GB_X": 8.0, "T02_X": 3.5}, {}, lathe=lathe)
    assert off["T02_X"] == 3.5
    with pytest.raises(TransformInputError, match="GB_X"):
        offsets_from_errors({"T01_X": 1.0}, {}, lathe=lathe)


def test_tool_offset_model_fit_recovers_a_known_relation():
    rng = np.random.default_rng(7)
    e_tls = rng.uniform(-5, 25, 200)
    e_tool = e_tls + 1.5 + 0.2 * e_tls + rng.normal(0, 0.3, e_tls.size)
    m = fit_tool_offset_model(e_tls, e_tool)
    assert m.intercept_um == pytest.approx(1.5, abs=0.15)
    assert m.gain == pytest.approx(0.2, abs=0.01)


def test_lathe_spec_from_mapping_names_bad_keys():
    lathe = LatheToolOffsets.from_mapping({"tls_component": "GB_X",
                                           "tools": {"T01_X": {"intercept_um": 1.0, "gain": 0.1}}})
    assert lathe.tools["T01_X"] == ToolOffsetModel(1.0, 0.1)
    with pytest.raises(TransformInputError, match=r"tools\.T01_X.*slope"):
        LatheToolOffsets.from_mapping({"tools": {"T01_X": {"slope": 1.0}}})
    with pytest.raises(TransformInputError, match=r"tools\.T01_X\.gain"):
        LatheToolOffsets.from_mapping({"tools": {"T01_X": {"gain": "nan"}}})


@pytest.mark.parametrize("b_deg", [0.0, 90.0, 30.0])
def test_applied_offsets_in_component_space_is_what_the_probe_cycle_stops_seeing(b_deg):
    """Hold constant offsets, probe the twin's sphere at the four C indexings, evaluate the
    cycle (eq. 5.4-5.7 style averages): only E_X0C/E_Y0C/E_Z0T drop, by exactly this mapping."""
    from thermal_twin.machine.artefact_geometry import true_sphere_centre
    errors = dict(E_X0C=3.0, E_Y0C=-7.0, E_Z0T=12.0, E_R0T=4.0, E_A0C=-15.0, E_B0C=6.0, E_C0C=9.0)
    offsets = {"X": 2.0, "Y": -5.0, "Z": 8.0}
    centres = {c: np.array(true_sphere_centre(c, b_deg, errors, offsets))
               - np.array(true_sphere_centre(c, b_deg, errors, {})) for c in (0.0, 90.0, 180.0, 270.0)}
    shift_um = np.mean(list(centres.values()), axis=0) * 1000.0     # the same at every indexing
    assert all(np.allclose(v * 1000.0, shift_um, atol=1e-9) for v in centres.values())
    comp = applied_offsets_in_component_space(offsets, b_deg)
    b = math.radians(b_deg)
    # table-frame translation the probe sees: R_y(B)^T (machine shift of minus the offsets)
    t = np.array([[math.cos(b), 0, -math.sin(b)], [0, 1, 0], [math.sin(b), 0, math.cos(b)]]) @ (-shift_um)
    assert [comp["E_X0C"], comp["E_Y0C"], comp["E_Z0T"]] == pytest.approx(list(t), abs=1e-9)
    assert comp["E_R0T"] == comp["E_A0C"] == comp["E_B0C"] == comp["E_C0C"] == 0.0
    # round trip with the forward transform at the origin
    back = five_axis_offsets_um({**{c: 0.0 for c in FIVE_AXIS_COMPONENTS},
                                 **{k: comp[k] for k in ("E_X0C", "E_Y0C", "E_Z0T")}}, 0, 0, 0, b_deg)
    assert back == pytest.approx(offsets, abs=1e-12)


def test_lathe_tools_load_from_yaml_and_a_bad_file_names_the_parameter(tmp_path):
    from cnc_bridge.error_transform import load_lathe_tools
    assert load_lathe_tools("") is None
    bad = tmp_path / "tools.yaml"
    bad.write_bytes(b"\xff\xfe: [")
    with pytest.raises(ValueError, match="lathe_tools_file"):
        load_lathe_tools(str(bad))
    with pytest.raises(ValueError, match="lathe_tools_file"):
        load_lathe_tools(str(tmp_path / "missing.yaml"))
