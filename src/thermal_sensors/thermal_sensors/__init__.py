"""Temperature publishers: twin, CSV replay and Modbus RTD modules."""
