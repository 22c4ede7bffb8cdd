"""The mismatch finder (``thermal-comp diagnose``): locate where twin and machine disagree,
name the physics left out from the effect library, model it and prove the fit on held-out data."""
