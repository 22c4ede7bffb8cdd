"""Running the twin: whole time lines or step by step, scenarios and their profiles, the
checkpoint, the type's soft sensors and a synthetic plant with known dynamics."""
