"""TALC parameter sweeps over the Blaser thesis's Table 6.1 grid (``thermal-comp sweep``)."""
