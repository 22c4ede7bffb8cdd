"""``thermal-comp evaluate``: every model against honest baselines on a recording, open loop
and adaptive."""
