"""Live view: the ESDF slice, the pointmap, the robot and its commands, in Rerun."""
