"""Online learning between shifts: the model's twin learned from the cell's own recording while
the cell runs, its prior adopted only on learn's held-out test, swapped in atomically, audited.

The learning itself is ``thermal-comp learn`` (package thermal_eval, above this one in the
package DAG): it is reached only through the ``thermal-comp`` command in a subprocess of its own,
never imported. Here: when to learn (``schedule``), the subprocess with its timeout
(``learn_job``), what learn's report decides (``learn_report``), the run's history a new model is
warmed over (``history``), the checked, warmed, atomic swap in the model node (``prior_swap``),
the audit lines (``audit``) and the learner's core (``learner``). No rclpy. docs/learn.md,
section "Online learning".
"""
