"""When and how a model probes: the probing-cycle state machine, change- and load-driven
probing, probe-driven updates of open-loop models and the uncertainty-weighted hold."""
