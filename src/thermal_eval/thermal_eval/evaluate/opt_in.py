"""The models ``thermal-comp evaluate`` runs only when asked for (``--models`` / ``--also``).

The static GP dominated the wall time on FL_THERMAL and was worse than the training mean there;
the lagged ridge's gain update repeats the lagged ridge's grid search and was worse than it on
FL_THERMAL's held-out rows (docs/evaluate.md). A module of its own so that the command line's
help names them without importing the models.
"""

OPT_IN = ("gp_static", "lagged_ridge_gain_update", "arx_subgrid_gain_forgetting", "lagged_ridge_refit",
          "lowpass_ridge_refit")
