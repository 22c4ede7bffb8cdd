"""The thermal-comp command: launcher, inspection, record/replay, rerun view, demo and benchmarks."""
