"""The real FL_THERMAL spindle recording: loader, benchmark, adaptive replays and the
mechanism studies of a twin calibrated on it."""
