"""Joystick gateway (evdev Extreme 3D Pro → cmd/ref) and keyboard teleop."""
