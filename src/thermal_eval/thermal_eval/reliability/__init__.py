"""Fault injection and what must survive it: sensors, probes, CNC links, hangs, full disks,
process kills and attacks on a running cell."""
