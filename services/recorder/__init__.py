"""Record every key of a robot to MCAP, and replay a recording with its original timing."""
