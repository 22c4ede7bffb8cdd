"""Unit-to-unit variation: seeded, within the stated tolerances, a valid machine that differs."""
import pytest
import yaml

from thermal_twin.machine.instance import TOLERANCES, machine_instance, write_instance
from thermal_twin.machine.schema import _read_yaml, load_machine
from thermal_twin.machine.spec import MachineSpecError


def test_same_seed_same_machine_other_seed_other_machine():
    assert machine_instance("nmv5000", 3) == machine_instance("nmv5000", 3)
    assert machine_instance("nmv5000", 3) != machine_instance("nmv5000", 4)


def test_every_parameter_within_its_tolerance_and_some_changed():
    nominal, _ = _read_yaml("nmv5000")
    inst = machine_instance("nmv5000", 1)
    ratios = []
    for name, node in nominal["nodes"].items():
        r = inst["nodes"][name]["capacity"] / node["capacity"]
        assert abs(r - 1) <= TOLERANCES["capacity"] + 1e-12
        ratios.append(r)
    for name, link in nominal["links"].items():
        if link.get("conductance", 0.0) > 0:
            assert abs(inst["links"][name]["conductance"] / link["conductance"] - 1) <= TOLERANCES["conductance"] + 1e-12
    for name, err in nominal["errors"].items():
        for node, gain in err["terms"].items():
            assert abs(inst["errors"][name]["terms"][node] / gain - 1) <= TOLERANCES["error_gain"] + 1e-12
    assert max(abs(r - 1) for r in ratios) > 0.01
    assert inst["name"] == "nmv5000"          # scenarios are keyed by the type's name
    assert "unit #1" in inst["description"]


def test_zero_tolerance_is_the_nominal_machine():
    nominal, _ = _read_yaml("nmv5000")
    inst = machine_instance("nmv5000", 2, {k: 0.0 for k in TOLERANCES})
    assert inst["nodes"] == nominal["nodes"]
    assert inst["errors"] == nominal["errors"]


def test_written_instance_loads(tmp_path):
    p = write_instance(tmp_path / "unit.yaml", "nmv5000", 5)
    assert load_machine(str(p)).name == "nmv5000"
    assert yaml.safe_load(p.read_text())["description"].startswith("nmv5000 unit #5")


@pytest.mark.parametrize("seed, tol, field", [(-1, {}, "seed"), (1, {"capacity": 1.5}, "capacity"),
                                              (1, {"mass": 0.1}, "mass")])
def test_bad_input_names_the_field(seed, tol, field):
    with pytest.raises(MachineSpecError, match=field):
        machine_instance("nmv5000", seed, tol)
