"""The training load programmes and seeds of the machine-type priors (``thermal-comp prior``, the
demo's default prior); plain data, so that the command's help names them without the fitting code.
"""

#: Training load programmes of the prior, per model kind and machine type (the twin's name);
#: the LAST one is held out (TALC: to choose the orders; AGP: validation RMS; CD: input choice).
#: The demo's runs (talc-178h-dry, lathe-random-speed) are not among them.
TRAINING_SCENARIOS = {
    "talc": {"nmv5000": ["load-case-A", "load-case-B", "load-case-D", "talc-144h-mwf", "load-case-C"]},
    "cd": {"nmv5000": ["load-case-A", "load-case-B", "load-case-D", "talc-144h-mwf", "load-case-C"]},
    "agp": {"swiss_lathe": ["lathe-oil-steps", "lathe-door-openings", "lathe-test-piece"]},
}
#: Seeds of the training runs: 101, 102, ... (the demo's runs use seeds 0-99).
SEED_BASE = 101
