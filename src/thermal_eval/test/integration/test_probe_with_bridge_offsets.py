"""The probe cycle reads zero when the bridge compensates: probe_cycle's engine against
cnc_bridge's offsets (an integration test of two packages, so it lives above both)."""
from __future__ import annotations

import dataclasses

import pytest

from cnc_bridge.error_transform import offsets_from_errors
from probe_cycle.probe_backend import ArtefactModelBackend, ProbeBackend
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine
from thermal_twin.machine.artefact_geometry import (SPHERE_COMPONENTS, ArtefactGeometry, GuideBushArtefact,
                                            TouchProbeModel, nominal_sphere_centre)

# eq. 5.4-5.10 are first order; second-order terms stay below 1e-3 um or um/m here
EXACT_TOL = 2e-3
IDEAL = ArtefactGeometry(
    probe=dataclasses.replace(TouchProbeModel(), axis_resolution_um=0.0),
    guide_bush=dataclasses.replace(GuideBushArtefact(), level_spacing_um=0.0))


def _engine() -> ProbeCycleEngine:
    return ProbeCycleEngine(IDEAL)


def _reference(engine, backend):
    r = engine.run(GoalSpec(set_reference=True), backend)
    assert r.success and r.is_reference, r.message
    return r


def test_cycle_reads_zero_when_the_bridge_compensates_with_default_settings():
    """Offsets from cnc_bridge's default HTM (rigid convention, default origin), computed at
    the sphere position of each touch, cancel all seven errors in the probe's reading."""
    true = {"E_X0C": 6.0, "E_Y0C": -14.0, "E_Z0T": 21.0, "E_R0T": 5.0, "E_A0C": 30.0,
            "E_B0C": -25.0, "E_C0C": 40.0}

    class Compensated(ProbeBackend):
        name = "compensated"

        def __init__(self):
            self.inner = ArtefactModelBackend(errors={}, geometry=IDEAL)

        def touch(self, move):
            x, y, z = nominal_sphere_centre(move.c_axis_deg, IDEAL)
            self.inner.offsets_um = offsets_from_errors(self.inner.errors,
                                                        {"X": x, "Y": y, "Z": z, "B": 0.0})
            return self.inner.touch(move)

    backend = Compensated()
    backend.inner.errors = {c: 0.0 for c in SPHERE_COMPONENTS}
    engine = _engine()
    _reference(engine, backend)
    backend.inner.errors = true
    r = engine.run(GoalSpec(), backend)
    assert r.success, r.message
    for c, v in r.errors.as_dict().items():
        assert v == pytest.approx(0.0, abs=EXACT_TOL), c
