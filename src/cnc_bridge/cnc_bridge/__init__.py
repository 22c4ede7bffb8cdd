"""Predicted thermal errors to bounded, rate-limited CNC axis offsets over OPC UA."""
