"""The twin's physics: the lumped thermal network, the thermo-elastic error map, the sensor
model and the thesis's reference rod."""
