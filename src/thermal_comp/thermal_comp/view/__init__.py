"""rerun: mapping our messages to entities, the sinks (file, web viewer, spawned viewer), the live
view node and ``thermal-comp view``."""
