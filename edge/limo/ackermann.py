"""The LIMO's Ackermann steering as AgileX's own software computes it (pure functions).

The bridge and the chassis emulator both import these, so the two agree by construction:

* **Geometry** (``protocol.platforms``, shared with the simulator). The chassis steers its front
  wheels; the *central* angle c is the bicycle
  model's (a virtual wheel on the centre line, rear-axle radius r = L / tan c), the *inner*
  angle i the angle of the wheel on the inside of the turn, whose radius is r − T/2:
  tan i = L / (r − T/2). With the wheelbase L and track T the two convert exactly into each other.
* **Wire scale.** The ``0x111`` steering field is not an angle of either kind: AgileX's driver
  sends the inner angle divided by 1.64, and reads the ``0x221`` steering feedback back as the
  inner angle by multiplying with 2.47 (positive, a left turn) or 1.64 (negative).
* **Limit.** 0.48869 rad (28°) is the inner wheel's limit; the central limit, and the
  minimum turning radius, follow from it and the geometry (``max_central_angle``).

Sources, read for their formulas (agilexrobotics/limo_ros at 4c78efc):

* ``limo_base/src/limo_driver.cpp``: ``LimoDriver::twistCmdCallback`` (r = v/ω, central angle,
  inner angle, clamp, steering field = inner / ``right_angle_scale_`` for *both* signs),
  ``convertCentralAngleToInner``, ``convertInnerAngleToCentral``, ``parseFrame``
  (``MSG_MOTION_STATE_ID``: ×``left_angle_scale_`` if > 0 else ×``right_angle_scale_``),
  ``publishOdometry`` (``MODE_ACKERMANN``: ω = ±v / r from the inner angle).
* ``limo_base/include/limo_driver.h``: ``left_angle_scale_ = 2.47``, ``right_angle_scale_ = 1.64``,
  ``wheelbase_ = 0.2``, ``track_ = 0.172``, ``max_inner_angle_ = 28.0`` ("degree"), which the
  callback compares with an angle in radians, so it never clamps there.
* pylimo 0.3.5, ``pylimo/limo.py``, ``LIMO.__init__``: ``max_inner_angle = 0.48869`` (28° in
  radians), ``left_angle_scale = 2.47``, ``right_angle_scale = 1.64``. Its commented-out
  ``LIMO.SetMotionCommand`` divides a positive inner angle by 2.47; the live ROS driver divides
  by 1.64 whatever the sign, and that is what is followed here (limo_ros2 uses 2.47 for both,
  a third variant: the reference this project follows is limo_ros).
"""

from __future__ import annotations

# The geometry is the platform's (the simulator steers with it too); the wire scale below is the LIMO's.
from riskfield.protocol.platforms import central_to_inner, inner_to_central, min_turning_radius

__all__ = ["COMMAND_SCALE", "FEEDBACK_SCALE_LEFT", "FEEDBACK_SCALE_RIGHT", "central_to_inner", "feedback_field",
           "inner_from_command_field", "inner_from_feedback_field", "inner_to_central", "max_central_angle",
           "min_turning_radius", "steering_field"]

#: ``0x111``: the steering field is the inner angle divided by this, whatever the sign
#: (limo_driver.cpp ``twistCmdCallback``; ``right_angle_scale_``).
COMMAND_SCALE = 1.64
#: ``0x221``: a positive steering field times this is the inner angle (``left_angle_scale_``) …
FEEDBACK_SCALE_LEFT = 2.47
#: … and a negative or zero one times this (``right_angle_scale_``; limo_driver.cpp ``parseFrame``).
FEEDBACK_SCALE_RIGHT = 1.64


def max_central_angle(wheelbase: float, track: float, max_inner: float) -> float:
    """The central angle at the inner wheel's limit (``PlanarPlatform.max_central_steering`` for the LIMO)."""
    return inner_to_central(max_inner, wheelbase, track)


def steering_field(inner: float) -> float:
    """The ``0x111`` steering field (rad before the ×1000 of the wire) for an inner wheel angle."""
    return inner / COMMAND_SCALE


def inner_from_command_field(field: float) -> float:
    """The inner wheel angle a ``0x111`` steering field asks for: the chassis side of ``steering_field``."""
    return field * COMMAND_SCALE


def inner_from_feedback_field(field: float) -> float:
    """The inner wheel angle a ``0x221`` steering field reports (limo_driver.cpp ``parseFrame``)."""
    return field * (FEEDBACK_SCALE_LEFT if field > 0 else FEEDBACK_SCALE_RIGHT)


def feedback_field(inner: float) -> float:
    """The ``0x221`` steering field that reports an inner wheel angle: the chassis side of
    ``inner_from_feedback_field`` (what the emulator sends)."""
    return inner / (FEEDBACK_SCALE_LEFT if inner > 0 else FEEDBACK_SCALE_RIGHT)
