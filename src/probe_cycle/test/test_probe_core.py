"""Pure core of the probe cycle against the physical forward model (no ROS)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from thermal_twin.machine.artefact_geometry import (ARTEFACT_GUIDE_BUSH, ARTEFACT_SPHERE,
                                            SPHERE_COMPONENTS, ArtefactGeometry,
                                            GuideBushArtefact, SphereArtefact, TouchProbeModel,
                                            nominal_sphere_centre, touch_trigger_position)
from probe_cycle.cycle_plan import CyclePlan, PlanError, plan_sphere_cycle
from probe_cycle.cycle_reference import ReferenceFileError, ReferenceStore
from probe_cycle.probe_backend import ArtefactModelBackend, ProbeBackend, TouchReply
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine

# Exact recovery: eq. 5.4-5.10 are first-order; the forward model turns the table by exact
# rotations, so the second-order terms (error x error / radius) stay below 1e-3 um or um/m
# for errors of tens of um and um/m.
EXACT_TOL = 2e-3

IDEAL = ArtefactGeometry(
    probe=dataclasses.replace(TouchProbeModel(), axis_resolution_um=0.0),
    guide_bush=dataclasses.replace(GuideBushArtefact(), level_spacing_um=0.0))


def _engine(geometry=IDEAL, **kw) -> ProbeCycleEngine:
    return ProbeCycleEngine(geometry, **kw)


def _reference(engine, backend):
    r = engine.run(GoalSpec(set_reference=True), backend)
    assert r.success, r.message
    assert r.is_reference
    return r


OTHER_MACHINE = dataclasses.replace(
    IDEAL, sphere=SphereArtefact(radius_from_c_axis_mm=120.0, diameter_mm=20.0,
                                 centre_height_mm=60.0, c_axis_xy_mm=(250.0, -40.0),
                                 table_surface_z_mm=300.0))


@pytest.mark.parametrize("seed, geometry", [(1, IDEAL), (2, IDEAL), (3, OTHER_MACHINE)])
def test_noise_free_sphere_cycle_recovers_all_seven_errors(seed, geometry):
    rng = np.random.default_rng(seed)
    engine = _engine(geometry)
    base = {c: float(v) for c, v in zip(SPHERE_COMPONENTS, rng.uniform(-30, 30, 7))}
    backend = ArtefactModelBackend(errors=base, geometry=geometry)
    _reference(engine, backend)
    delta = {c: float(v) for c, v in zip(SPHERE_COMPONENTS, rng.uniform(-40, 40, 7))}
    backend.errors = {c: base[c] + delta[c] for c in SPHERE_COMPONENTS}
    r = engine.run(GoalSpec(), backend)
    assert r.success, r.message
    got = r.errors.as_dict()
    for c in SPHERE_COMPONENTS:
        assert got[c] == pytest.approx(delta[c], abs=EXACT_TOL), c
    units = dict(zip(r.errors.component_names, r.errors.units))
    assert [units[c] for c in SPHERE_COMPONENTS] == ["um"] * 4 + ["um/m"] * 3
    assert r.duration_s == pytest.approx(95.0)
    assert r.fit_residual_rms_um < 1e-6
    assert r.repeatability_check_um < 1e-6


def test_each_error_alone_has_the_thesis_sign():
    """One error at a time: a positive true error is measured positive, nothing leaks."""
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    _reference(engine, backend)
    for comp in SPHERE_COMPONENTS:
        backend.errors = {comp: 12.5}
        got = engine.run(GoalSpec(), backend).errors.as_dict()
        for c in SPHERE_COMPONENTS:
            assert got[c] == pytest.approx(12.5 if c == comp else 0.0, abs=EXACT_TOL), (comp, c)


def test_sphere_sits_at_minus_x_plus_y_plus_x_minus_y():
    p = [nominal_sphere_centre(c) for c in (0, 90, 180, 270)]
    assert p[0][0] == pytest.approx(-160) and p[1][1] == pytest.approx(160)
    assert p[2][0] == pytest.approx(160) and p[3][1] == pytest.approx(-160)


def test_probe_measures_true_error_minus_applied_offset():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    _reference(engine, backend)
    backend.errors = {"E_X0C": 10.0, "E_Y0C": -8.0, "E_Z0T": 15.0}
    backend.offsets_um = {"X": 4.0, "Y": -8.0, "Z": 20.0}
    got = engine.run(GoalSpec(), backend).errors.as_dict()
    assert got["E_X0C"] == pytest.approx(6.0, abs=EXACT_TOL)
    assert got["E_Y0C"] == pytest.approx(0.0, abs=EXACT_TOL)
    assert got["E_Z0T"] == pytest.approx(-5.0, abs=EXACT_TOL)


def test_noise_free_guide_bush_recovered_with_zero_at_first_cycle():
    engine = _engine()
    backend = ArtefactModelBackend(errors={"GB_X": 3.0}, geometry=IDEAL)
    first = engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
    assert first.success and first.is_reference
    assert first.errors.as_dict() == {"GB_X": 0.0}
    backend.errors = {"GB_X": 3.0 + 17.25}
    r = engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH, tool_position="GB"), backend)
    assert r.success, r.message
    assert r.errors.as_dict()["GB_X"] == pytest.approx(17.25, abs=1e-6)
    assert r.errors.units == ("um",)
    backend.errors = {"GB_X": 3.0 - 5.0}
    backend.offsets_um = {"GB_X": -2.0}
    r = engine.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
    assert r.errors.as_dict()["GB_X"] == pytest.approx(-3.0, abs=1e-6)


def test_guide_bush_skips_on_discrete_levels_within_half_micron():
    rng = np.random.default_rng(7)
    g = GuideBushArtefact()
    start = np.array([g.face_x_mm + 0.05, 0.0, 0.0])
    xs = []
    for _ in range(400):
        ok, pos = touch_trigger_position(ARTEFACT_GUIDE_BUSH, 0, 0, start,
                                         np.array([-1.0, 0, 0]), 0.1, {"GB_X": 0.0}, {},
                                         rng=rng)
        assert ok
        xs.append(pos[0] * 1000.0)
    xs = np.array(xs)
    levels = xs / g.level_spacing_um
    assert np.allclose(levels, np.round(levels), atol=1e-6)
    centre = (g.face_x_mm * 1000.0 - g.overstroke_um)
    assert np.max(np.abs(xs - centre)) <= g.repeatability_um + g.level_spacing_um / 2 + 1e-9
    assert len(np.unique(np.round(xs, 3))) > 3      # it does scatter


def test_probe_triggers_only_on_supported_directions():
    centre = nominal_sphere_centre(0.0)
    start = centre + np.array([-30.0, 0.0, 0.0])
    ok, pos = touch_trigger_position(ARTEFACT_SPHERE, 0, 0, start, np.array([1.0, 0, 0]),
                                     40.0, {}, {})
    assert not ok            # a lateral move would hit the sphere, but the probe is 2.5D
    assert pos == pytest.approx(start + [40.0, 0, 0])
    ok, _ = touch_trigger_position(ARTEFACT_SPHERE, 0, 0, centre + [0, 0, 30.0],
                                   np.array([0, 0, -1.0]), 40.0, {}, {})
    assert ok
    ok, _ = touch_trigger_position(ARTEFACT_GUIDE_BUSH, 0, 0, np.array([12.05, 0, 0]),
                                   np.array([1.0, 0, 0]), 1.0, {}, {})
    assert not ok            # moving away from the guide-bush face


@pytest.mark.parametrize("kwargs, field", [
    (dict(direction=np.array([0, 0, -2.0])), "direction"),
    (dict(start_mm=np.array([0, np.nan, 0])), "start_mm"),
    (dict(max_travel_mm=-1.0), "max_travel_mm"),
    (dict(errors={"E_X0C": float("inf")}), "errors['E_X0C']"),
    (dict(artefact=7), "artefact"),
])
def test_forward_model_bad_input_names_the_field(kwargs, field):
    args = dict(artefact=ARTEFACT_SPHERE, c_axis_deg=0.0, b_axis_deg=0.0,
                start_mm=nominal_sphere_centre(0.0) + [0, 0, 20.0],
                direction=np.array([0, 0, -1.0]), max_travel_mm=10.0, errors={},
                applied_offsets_um={})
    args.update(kwargs)
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        touch_trigger_position(**args)


def test_hundred_cycles_on_warm_steady_twin_match_table_5_4():
    """100 cycles with the probe model's scatter and 1 um resolution: U(k=2) per error."""
    rng = np.random.default_rng(2020)
    geometry = ArtefactGeometry()
    engine = ProbeCycleEngine(geometry)
    warm = {"E_X0C": 4.0, "E_Y0C": 18.0, "E_Z0T": -21.0, "E_R0T": 6.0, "E_A0C": 12.0,
            "E_B0C": -7.0, "E_C0C": 3.0}
    backend = ArtefactModelBackend(errors=warm, geometry=geometry, rng=rng)
    _reference(engine, backend)
    values, reported_u = [], []
    for _ in range(100):
        r = engine.run(GoalSpec(), backend)
        assert r.success, r.message
        values.append(r.errors.values)
        reported_u.append(r.errors.uncertainties)
    values, reported_u = np.array(values), np.array(reported_u)
    u_emp = values.std(axis=0, ddof=1)
    # reported u = cycle (+) reference in quadrature; the scatter with a common reference
    # shows the cycle's part only, i.e. reported / sqrt(2)
    u_cycle = reported_u.mean(axis=0) / np.sqrt(2.0)
    table_5_4 = {"E_X0C": 0.4, "E_Y0C": 0.5, "E_Z0T": 0.4, "E_R0T": 0.6, "E_A0C": 2.3,
                 "E_B0C": 2.5, "E_C0C": 2.6}
    print("\ncomponent   U(k=2) measured   U(k=2) fit+probe model   Table 5.4")
    for i, c in enumerate(SPHERE_COMPONENTS):
        print(f"{c:8s} {2 * u_emp[i]:12.2f} {2 * u_cycle[i]:18.2f} {table_5_4[c]:16.1f}")
    for i, c in enumerate(SPHERE_COMPONENTS):
        assert 0.5 * table_5_4[c] <= 2 * u_emp[i] <= 2.0 * table_5_4[c], c
        assert u_emp[i] == pytest.approx(u_cycle[i], rel=0.3), c


# ------------------------------------------------------------------ failure modes
class ChipOnSphere(ProbeBackend):
    """A chip on the sphere: one touch at C=180 triggers 25 um early."""

    name = "chip"

    def __init__(self, inner: ProbeBackend):
        self.inner = inner

    def touch(self, move):
        reply = self.inner.touch(move)
        if move.stage == "C=180 point 3/5":
            return TouchReply(reply.triggered, reply.position_mm + [0, 0, 0.025], reply.stamp_s)
        return reply


def _assert_failed(result, text):
    assert not result.success
    assert result.errors is None                      # nothing published as measured
    assert text in result.message, result.message


def test_missing_trigger_fails_and_keeps_reference():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    ref = _reference(engine, backend)
    before = engine.references.sphere
    backend.errors = {"E_Z0T": -5000.0}            # sphere 5 mm lower: out of reach
    r = engine.run(GoalSpec(set_reference=True), backend)
    _assert_failed(r, "missing trigger at C=0 point 1/5")
    assert r.points_done == 1
    assert engine.references.sphere is before
    assert ref.success


def test_fit_residual_above_limit_fails():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    _reference(engine, backend)
    r = engine.run(GoalSpec(), ChipOnSphere(backend))
    _assert_failed(r, "sphere fit at C=180: RMS residual")


def test_360_disagreeing_with_0_fails():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    _reference(engine, backend)
    t0 = backend.time_s
    backend.errors = lambda t: {"E_X0C": 0.1 * (t - t0)}   # 0.1 um/s drift, a crash-hot axis
    r = engine.run(GoalSpec(), backend)
    _assert_failed(r, "repeatability check failed: the centre at C=360")
    assert r.repeatability_check_um > 4.0


def test_timeout_in_simulated_time_fails():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    r = engine.run(GoalSpec(set_reference=True, timeout_s=50.0), backend)
    _assert_failed(r, "timeout")
    assert 0 < r.points_done < 25
    assert r.duration_s <= 50.0
    assert engine.references.sphere is None


def test_cancel_stops_before_the_next_point():
    engine = _engine()
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    done = []
    r = engine.run(GoalSpec(set_reference=True), backend,
                   on_point=lambda i, n, m, rep: done.append((i, n, m.stage)),
                   cancel_requested=lambda: len(done) >= 7)
    _assert_failed(r, "canceled before C=90 point 3/5")
    assert r.details["canceled"]
    assert done[-1] == (7, 25, "C=90 point 2/5")


@pytest.mark.parametrize("goal, text", [
    (GoalSpec(points_per_indexing=3), "points_per_indexing"),
    (GoalSpec(points_per_indexing=1000), "points_per_indexing"),
    (GoalSpec(c_angles_deg=(0.0, 90.0, 180.0)), "missing 270"),
    (GoalSpec(artefact=5), "artefact"),
    (GoalSpec(artefact=ARTEFACT_GUIDE_BUSH, tool_position="T01"), "tool_position"),
    (GoalSpec(timeout_s=-3.0), "timeout_s"),
])
def test_invalid_goals_fail_with_the_field_named(goal, text):
    engine = _engine()
    r = engine.run(goal, ArtefactModelBackend(errors={}, geometry=IDEAL))
    _assert_failed(r, text)


def test_guide_bush_scatter_above_limit_fails():
    class Slipping(ProbeBackend):
        name = "slipping"

        def __init__(self):
            self.inner = ArtefactModelBackend(errors={}, geometry=IDEAL)
            self.n = 0

        def touch(self, move):
            r = self.inner.touch(move)
            self.n += 1
            return TouchReply(True, r.position_mm + [0.006 * (self.n % 2), 0, 0], r.stamp_s)

    r = _engine().run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH, points_per_indexing=4), Slipping())
    _assert_failed(r, "guide-bush skips scatter")


def test_plan_durations_sum_to_95_s_and_starts_are_commanded_at_1_um():
    plan = plan_sphere_cycle(ArtefactGeometry())
    assert isinstance(plan, CyclePlan)
    assert len(plan.moves) == 25 and plan.duration_s == pytest.approx(95.0)
    starts = np.array([m.start_mm for m in plan.moves]) * 1000.0
    assert np.allclose(starts, np.round(starts), atol=1e-6)
    with pytest.raises(PlanError, match="c_angles_deg"):
        plan_sphere_cycle(ArtefactGeometry(), c_angles_deg=())


def test_reference_survives_a_restart_through_its_file(tmp_path):
    path = tmp_path / "ref.json"
    backend = ArtefactModelBackend(errors={"E_Y0C": 5.0, "GB_X": 1.0}, geometry=IDEAL)
    e1 = _engine(reference_path=path)
    _reference(e1, backend)
    e1.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
    e2 = _engine(reference_path=path)                 # a restarted server
    backend.errors = {"E_Y0C": 9.0, "GB_X": 3.5}
    assert e2.run(GoalSpec(), backend).errors.as_dict()["E_Y0C"] == pytest.approx(4.0, abs=1e-3)
    gb = e2.run(GoalSpec(artefact=ARTEFACT_GUIDE_BUSH), backend)
    assert gb.errors.as_dict()["GB_X"] == pytest.approx(2.5, abs=1e-6)


def test_bad_reference_file_names_the_key(tmp_path):
    path = tmp_path / "ref.json"
    data = ReferenceStore().to_dict()
    data["sphere"] = {"centres_um": [[0, 0, 0]] * 4, "covariances_um2": "x", "stamp_s": 0}
    path.write_text(json.dumps(data))
    with pytest.raises(ReferenceFileError, match="covariances_um2"):
        ReferenceStore.load(path)
    path.write_text("{not json")
    with pytest.raises(ReferenceFileError, match="not valid JSON"):
        ReferenceStore.load(path)


def test_analytic_jacobian_of_the_fit_matches_finite_differences():
    from probe_cycle.sphere_fit import _along_move_jacobian, _along_move_residuals
    rng = np.random.default_rng(11)
    plan = plan_sphere_cycle(ArtefactGeometry())
    moves = plan.moves_of_group(1)
    pts = np.array([m.start_mm for m in moves]) - [0, 0, 2.0]      # about on the sphere
    pts_um = (pts - np.asarray(plan.nominal_centres_mm[1])) * 1000.0
    dirs = np.array([m.direction for m in moves])
    r_um = plan.contact_radius_mm * 1000.0
    for _ in range(5):
        c = rng.normal(0.0, 30.0, 3)
        jac = _along_move_jacobian(c, pts_um, dirs, r_um)
        num = np.column_stack([
            (_along_move_residuals(c + h, pts_um, dirs, r_um)
             - _along_move_residuals(c - h, pts_um, dirs, r_um)) / 2e-3
            for h in np.eye(3) * 1e-3])
        assert np.allclose(jac, num, atol=1e-6)
