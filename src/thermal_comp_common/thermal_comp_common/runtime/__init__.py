"""How processes run: the node runtime (topics, QoS, parameters), /diagnostics, ROS domain ids,
child processes, the task engine (local or Dask) and single-thread BLAS."""
