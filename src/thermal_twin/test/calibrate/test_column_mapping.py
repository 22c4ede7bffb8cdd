"""Real files: Excel-style CSVs (BOM, ';', decimal comma) and a column mapping, with the
name mismatches reported with their closest match."""
from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest

from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.column_mapping import MappingError, name_mismatches, parse_mapping, read_real_recording
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.simulate import simulate
from thermal_eval.diagnose.concealed import operating_programme

TWIN = pathlib.Path(__file__).parents[1] / "diagnose" / "mini_mill.yaml"
NAMES = {"time_s": "Zeit_s", "spindle_rpm": "Drehzahl", "ambient_c": "T_Halle", "spindle_c": "T_Spindel",
         "head_c": "T_Kopf", "column_c": "T_Saeule", "table_c": "T_Tisch", "E_Z0T": "Z_axial", "E_X0C": "X"}


def _excel_csv(path: pathlib.Path, rec, flip: str) -> None:
    names = ["time_s"] + [c for c in rec.columns if c in NAMES]
    lines = [";".join(NAMES[n] for n in names)]
    for i in range(len(rec)):
        vals = [rec.time_s[i]] + [rec.columns[n][i] * (-1 if n == flip else 1) for n in names[1:]]
        lines.append(";".join(f"{v:.6f}".replace(".", ",") for v in vals))
    path.write_text("\ufeff" + "\r\n".join(lines) + "\r\n", encoding="utf-8")


@pytest.fixture(scope="module")
def excel(tmp_path_factory):
    m = load_machine(TWIN)
    rec = simulate(m, operating_programme(m.to_dict(), 12.0, 300.0, seed=2), seed=0).to_recording()
    path = tmp_path_factory.mktemp("xl") / "messung.csv"
    _excel_csv(path, rec, flip="E_Z0T")
    return m, rec, path


def test_excel_csv_with_mapping_reads_back_the_twin_columns(excel):
    m, rec, path = excel
    mapping = parse_mapping(flags=[f"{v}={k}" for k, v in NAMES.items() if k != "E_Z0T"]
                            + ["Z_axial=E_Z0T", "E_Z0T*-1"])
    got = read_real_recording(path, mapping)
    assert any("byte-order mark" in w for w in got.warnings)
    assert any("decimal comma" in w for w in got.warnings)
    np.testing.assert_allclose(got.time_s, rec.time_s, atol=1e-6)
    for c in ("spindle_rpm", "head_c", "E_Z0T", "E_X0C"):
        np.testing.assert_allclose(got.columns[c], rec.columns[c], atol=1e-5)
    assert [w for w in name_mismatches(m, got) if "door_open" not in w and "coolant_on" not in w] == []


def test_mismatched_names_are_reported_with_the_closest_match(excel):
    m, _, path = excel
    with pytest.raises(MappingError, match=r"'T_Kopp' is not in messung.csv \(closest: T_Kopf\)"):
        read_real_recording(path, parse_mapping(flags=["Zeit_s=time_s", "T_Kopp=head_c"]))
    with pytest.raises(MappingError, match="expected OLD=NEW"):
        parse_mapping(flags=["nonsense"])
    got = read_real_recording(path, parse_mapping(flags=["Zeit_s=time_s", "T_Kopf=head_cc"]))
    notes = name_mismatches(m, got)
    assert "recording column 'head_cc' is not a twin sensor, channel or input (closest: head_c)" in notes
    assert "twin column 'head_c' is not in the recording (closest: head_cc)" in notes


def test_calibrate_accepts_the_excel_file_with_a_mapping_file(excel, tmp_path):
    _, _, path = excel
    mf = tmp_path / "map.yaml"
    mf.write_text("columns: {" + ", ".join(f"{v}: {k}" for k, v in NAMES.items()) + "}\nscale: {E_Z0T: -1}\n")
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(path), "--map-file", str(mf), "--out", str(out),
                 "--quiet", "--max-nfev", "2"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert set(rep["channels"]) == {"ambient_c", "spindle_c", "head_c", "column_c", "table_c", "E_Z0T", "E_X0C"}
    # the sign flip was undone: the twin fits E_Z0T as well as it fits itself
    assert rep["channels"]["E_Z0T"]["holdout_rmse_before"] < 0.1
