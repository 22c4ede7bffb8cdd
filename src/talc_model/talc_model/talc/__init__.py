"""TALC, Thermal Adaptive Learning Control (Blaser thesis ch. 6): the model, its configuration,
identification, grid and probing schedule."""
