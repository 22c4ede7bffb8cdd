"""Characteristic diagrams: the grid regression, input selection, the load-case update and
the adaptive model behind the shared protocol."""
