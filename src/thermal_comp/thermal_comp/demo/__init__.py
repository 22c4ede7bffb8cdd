"""``thermal-comp demo``: the demo cell, its graph run, the in-process monitor, and the summary,
series and plots of a run."""
