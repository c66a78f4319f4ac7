"""Code that touches hardware: LIMO serial bridge, joystick gateway, MAVLink bridge."""
