"""Priors of the machine type for TALC, the AGP and characteristic diagrams, identified on
virtual experiments of the type's twin."""
