"""In a production cell's processes (THERMAL_COMP_PRODUCTION=1) the CNC side refuses open
access by itself: the emulator with --security optional and no trust list exits 2 with one
line, and a bridge configuration without security_required is refused."""
import pytest

from cnc_bridge.cnc_emulator.cli import build_parser
from cnc_bridge.cnc_emulator.command import run
from cnc_bridge.opcua_config import OpcUaConfig, OpcUaConfigError
from thermal_comp_common.runtime.production import PRODUCTION_ENV, production_mode


def test_production_mode_reads_the_marker():
    assert production_mode({PRODUCTION_ENV: "1"}) and production_mode({PRODUCTION_ENV: "true"})
    assert not production_mode({}) and not production_mode({PRODUCTION_ENV: "0"})


def test_an_open_emulator_is_refused_in_a_production_cell(monkeypatch, capsys):
    monkeypatch.setenv(PRODUCTION_ENV, "1")
    assert run(build_parser().parse_args(["--port", "1", "--security", "optional"]), []) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "refused: --security optional without --client-trust" in err


def test_a_bridge_without_security_required_is_refused_in_a_production_cell(monkeypatch):
    OpcUaConfig(endpoint="opc.tcp://127.0.0.1:4840")          # a trial cell: allowed
    monkeypatch.setenv(PRODUCTION_ENV, "1")
    with pytest.raises(OpcUaConfigError, match=r"security_required: False in a production cell"):
        OpcUaConfig(endpoint="opc.tcp://127.0.0.1:4840")
