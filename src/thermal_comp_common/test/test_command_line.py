"""run_parsed: the one deferred import of the command line."""
import argparse
import subprocess
import sys

import pytest

from thermal_comp_common.command_line import add_sample_period_argument, run_parsed


def test_the_work_gets_every_argument_and_its_return_is_the_exit_code():
    assert run_parsed("operator:add", 2, 3) == 5
    assert run_parsed("builtins:len", []) == 0


def test_a_malformed_work_name_is_refused_naming_it():
    with pytest.raises(ValueError, match="'no_colon'"):
        run_parsed("no_colon", 1)


def test_the_work_module_is_imported_only_when_run():
    code = ("import sys\nfrom thermal_comp_common.command_line import run_parsed\n"
            "before = 'tomllib' in sys.modules\n"
            "run_parsed('tomllib:loads', '')\nprint(before, 'tomllib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True"]


def test_the_sample_period_option_is_a_float_absent_by_default():
    ap = argparse.ArgumentParser()
    add_sample_period_argument(ap)
    assert ap.parse_args([]).sample_period_s is None
    assert ap.parse_args(["--sample-period-s", "60"]).sample_period_s == 60.0
    with pytest.raises(SystemExit):
        ap.parse_args(["--sample-period-s", "a minute"])
