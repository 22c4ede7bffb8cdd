"""A cell file that says ``production: true`` opens no CNC to anyone: a bridge without
security_required or a CNC emulator with --security optional / no client trust list is refused
in one line naming the node's key, and every process of the cell is marked production."""
import pytest

from thermal_comp.cell.config import CellConfigError, parse_cell
from thermal_comp_common.runtime.production import PRODUCTION_ENV

BRIDGE = {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node", "lifecycle": True}
EMULATOR = {"name": "cnc", "module": "cnc_bridge.cnc_emulator",
            "args": ["--security", "required", "--client-trust", "pki/bridge.der"]}


def _cell(*nodes, production=True):
    return {"cell": "cell_p", "production": production, "nodes": list(nodes)}


def _one_line(exc_info) -> str:
    assert "\n" not in str(exc_info.value)
    return str(exc_info.value)


def test_a_secured_production_cell_is_accepted_and_marks_its_processes():
    cell = parse_cell(_cell({**BRIDGE, "parameters": {"security_required": True}}, EMULATOR), resolve=False)
    assert cell.production and cell.env[PRODUCTION_ENV] == "1"
    plain = parse_cell(_cell({**BRIDGE, "parameters": {"security_required": False}}, production=False),
                       resolve=False)
    assert not plain.production and PRODUCTION_ENV not in plain.env


@pytest.mark.parametrize("params", [{}, {"security_required": False}, {"security_required": "true"}])
def test_a_production_bridge_without_security_required_is_refused(params):
    with pytest.raises(CellConfigError, match=r"nodes\[0\]\.parameters\.security_required: is .* needs true") as e:
        parse_cell(_cell({**BRIDGE, "parameters": params}), source="cell.yaml", resolve=False)
    assert _one_line(e).startswith("cell.yaml: ")


@pytest.mark.parametrize("args, said", [
    ([], "--security optional without --client-trust"),
    (["--security", "optional", "--client-trust", "t.der"], "--security optional"),
    (["--security", "required"], "--security required without --client-trust"),
])
def test_a_production_emulator_open_to_anyone_is_refused(args, said):
    with pytest.raises(CellConfigError, match=r"nodes\[1\]\.args") as e:
        parse_cell(_cell({**BRIDGE, "parameters": {"security_required": True}}, {**EMULATOR, "args": args}),
                   resolve=False)
    assert said in _one_line(e)


def test_production_must_be_a_boolean():
    with pytest.raises(CellConfigError, match=r"production: expected true or false, got 'yes'"):
        parse_cell(_cell(BRIDGE, production="yes"), resolve=False)


def test_a_node_cannot_unmark_itself():
    node = {**BRIDGE, "parameters": {"security_required": True}, "env": {PRODUCTION_ENV: "0"}}
    with pytest.raises(CellConfigError, match=r"nodes\[0\]\.env\.THERMAL_COMP_PRODUCTION"):
        parse_cell(_cell(node), resolve=False)
