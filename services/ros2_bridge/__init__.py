"""ROS 2 interop through zenoh-bridge-ros2dds: raw CDR ``Twist`` out, ``Odometry`` in."""
