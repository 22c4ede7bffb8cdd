"""The closed loop temperatures -> model -> compensation -> probe, without ROS, and what it
needs around the model (applied compensation, slow-error filter)."""
