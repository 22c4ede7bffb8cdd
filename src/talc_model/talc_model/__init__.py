"""Adaptive thermal-error models: TALC (ARX), adaptive Gaussian process, characteristic diagrams."""
