"""ProbeCycle action server: sphere cycle of a 5-axis machine, guide-bush probing of a Swiss-type lathe."""
