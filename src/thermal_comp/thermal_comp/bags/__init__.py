"""Recording and replaying rosbag2 MCAP bags: the recorder and player nodes and the ``record``,
``play`` and ``import-csv`` commands."""
