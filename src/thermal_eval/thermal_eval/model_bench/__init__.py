"""Benchmarks of the adaptive models' own logic: the hold fall-back (``thermal-comp bench hold-fallback``)
and the prior from a machine's history (``thermal-comp bench history-prior``)."""
