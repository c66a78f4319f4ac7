"""MAVLink bridge for PX4/ArduPilot: cmd/safe → velocity setpoints, vehicle → state (ENU)."""
