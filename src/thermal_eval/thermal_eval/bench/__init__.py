"""``thermal-comp bench``: the performance benchmarks, one module per suite."""
