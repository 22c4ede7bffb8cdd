"""The machine description: YAML schema, validated spec, packaged presets, unit-to-unit
variation and the probing artefacts' geometry."""
