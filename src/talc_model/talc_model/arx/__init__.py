"""MISO ARX models: estimation, batched candidates, the observer update and order selection."""
