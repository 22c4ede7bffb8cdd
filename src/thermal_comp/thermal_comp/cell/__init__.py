"""Machine cells: cell files, the launch plan, the launcher of node processes, the lifecycle driver
and the inspection of a running graph (``topics``, ``nodes``, ``echo``)."""
