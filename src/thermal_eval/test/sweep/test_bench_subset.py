"""The combinations `thermal-comp bench models` runs: Table 6.1 points, the same rule for every case."""
from thermal_eval.bench.sweep import COARSE_GRID, TABLE_6_3_SETS, subset_points
from thermal_eval.sweep.grid import TALC_INPUTS, THESIS_TALC_INPUTS, table_6_1_grid


def test_subset_is_table_6_3_plus_coarse_factorial_on_the_grid():
    grid = set(table_6_1_grid(24.0))
    pts = subset_points(quick=False)
    assert len(pts) == len(set(pts))
    assert set(pts) <= grid
    sets = {(p.cp_length_h, p.post_cp_interval_h, p.ng_measurements, p.ng_interval_min) for p in pts}
    assert set(TABLE_6_3_SETS) <= sets
    n_coarse = 1
    for values in COARSE_GRID.values():
        n_coarse *= len(values)
    in_factorial = [p for p in pts if all(getattr(p, k) in v for k, v in COARSE_GRID.items())]
    assert n_coarse == 144 and len(in_factorial) == n_coarse
    assert len(pts) == 146          # the sets of B and D are factorial points themselves
    assert subset_points(quick=False, full=True) == table_6_1_grid(24.0)
    quick = subset_points(quick=True)
    assert len(quick) == 2 and all(p.cp_length_h == 8.5 for p in quick)


def test_sweep_inputs_are_the_thesis_three_plus_the_mwf_flag():
    assert TALC_INPUTS[:3] == THESIS_TALC_INPUTS and TALC_INPUTS[3:] == ("coolant_on",)
