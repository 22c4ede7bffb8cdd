"""A CNC that holds the location errors in its kinematic model compensates them at every
position: the probe then measures, component by component, true error minus applied value."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from probe_cycle.probe_backend import ArtefactModelBackend
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine
from thermal_twin.machine.artefact_geometry import (ArtefactGeometry, GuideBushArtefact, SPHERE_COMPONENTS,
                                            TouchProbeModel, split_compensation)

IDEAL = ArtefactGeometry(
    probe=dataclasses.replace(TouchProbeModel(), axis_resolution_um=0.0),
    guide_bush=dataclasses.replace(GuideBushArtefact(), level_spacing_um=0.0))
TOL = 2e-3


@pytest.mark.parametrize("seed", [4, 5])
def test_kinematic_compensation_is_seen_per_component(seed):
    rng = np.random.default_rng(seed)
    engine = ProbeCycleEngine(IDEAL)
    backend = ArtefactModelBackend(errors={}, geometry=IDEAL)
    assert engine.run(GoalSpec(set_reference=True), backend).success
    true = {c: float(v) for c, v in zip(SPHERE_COMPONENTS, rng.uniform(-30, 30, 7))}
    applied = {c: float(v) for c, v in zip(SPHERE_COMPONENTS, rng.uniform(-30, 30, 7))}
    backend.errors = true
    backend.offsets_um = dict(applied)
    got = engine.run(GoalSpec(), backend).errors.as_dict()
    for c in SPHERE_COMPONENTS:   # angular ones included: the CNC applies them everywhere
        assert got[c] == pytest.approx(true[c] - applied[c], abs=TOL), c
    backend.offsets_um = dict(true)
    got = engine.run(GoalSpec(), backend).errors.as_dict()
    assert max(abs(got[c]) for c in SPHERE_COMPONENTS) < TOL


def test_split_compensation_keeps_axis_offsets_and_names_bad_values():
    residual, axes = split_compensation({"E_A0C": 10.0, "E_Y0C": 3.0}, {"E_A0C": 4.0, "X": 1.5})
    assert residual == {"E_A0C": 6.0, "E_Y0C": 3.0} and axes == {"X": 1.5}
    with pytest.raises(ValueError, match="E_B0C"):
        split_compensation({}, {"E_B0C": float("nan")})
