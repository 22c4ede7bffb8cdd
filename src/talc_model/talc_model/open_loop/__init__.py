"""Open-loop regression on lagged temperatures, sensor selection, and the adaptive
compensators that update an open-loop model from probes (gain update, refit, load-driven probing)."""
