"""Physics simulator (digital twin) of machine cells and the mismatch finder."""
