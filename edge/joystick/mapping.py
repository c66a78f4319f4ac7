"""Joystick axes and buttons → a body velocity command (pure; no evdev import).

Logitech Extreme 3D Pro defaults (Linux evdev codes):

==================  ==========  ================================================
what                code        mapping
==================  ==========  ================================================
stick forward/back  ABS_Y       0..1023, pushed forward = low → inverted → +vx
stick left/right    ABS_X       unused by default (``-ABS_X`` → +vy for mecanum)
twist               ABS_RZ      0..255, twisted right = high → inverted → −ωz
throttle slider     ABS_THROTTLE 0..255, "+" end = low → inverted → speed scale 1
trigger             BTN_TRIGGER dead-man: released → zero command
==================  ==========  ================================================

An axis is written as a code name with an optional leading ``-`` for inversion, e.g.
``-ABS_Y``; an empty string leaves a command component unused. Each axis is normalised
to [−1, 1] over its range, then a deadzone around the centre is removed and the rest
rescaled, so the output is continuous: |x| ≤ d → 0, else sign(x)·(|x| − d)/(1 − d).
The speed scale maps the slider's [−1, 1] to [``min_scale``, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

EV_SYN, EV_KEY, EV_ABS = 0, 1, 3
SYN_REPORT, SYN_DROPPED = 0, 3

#: Linux input event codes this module understands by name (``linux/input-event-codes.h``).
CODES: dict[str, int] = {
    "ABS_X": 0x00, "ABS_Y": 0x01, "ABS_Z": 0x02, "ABS_RX": 0x03, "ABS_RY": 0x04, "ABS_RZ": 0x05,
    "ABS_THROTTLE": 0x06, "ABS_RUDDER": 0x07, "ABS_HAT0X": 0x10, "ABS_HAT0Y": 0x11,
    "BTN_TRIGGER": 0x120, "BTN_THUMB": 0x121, "BTN_THUMB2": 0x122, "BTN_TOP": 0x123, "BTN_TOP2": 0x124,
    "BTN_PINKIE": 0x125, "BTN_BASE": 0x126, "BTN_BASE2": 0x127, "BTN_BASE3": 0x128, "BTN_BASE4": 0x129,
    "BTN_BASE5": 0x12A, "BTN_BASE6": 0x12B, "BTN_SOUTH": 0x130, "BTN_EAST": 0x131, "BTN_TL": 0x136,
    "BTN_TR": 0x137,
}

#: Ranges of the Extreme 3D Pro, used until the device reports its own.
DEFAULT_RANGES: dict[int, tuple[int, int]] = {
    CODES["ABS_X"]: (0, 1023), CODES["ABS_Y"]: (0, 1023), CODES["ABS_RZ"]: (0, 255),
    CODES["ABS_THROTTLE"]: (0, 255), CODES["ABS_HAT0X"]: (-1, 1), CODES["ABS_HAT0Y"]: (-1, 1),
}


def parse_code(name: str | int) -> int:
    if isinstance(name, int):
        return name
    name = name.strip().upper()
    if name.isdigit():
        return int(name)
    if name not in CODES:
        raise ValueError(f"unknown input code {name!r}; known: {', '.join(CODES)} or a number")
    return CODES[name]


@dataclass(frozen=True)
class AxisSpec:
    """One axis: event code, raw range, inversion and deadzone (fraction of half-range)."""

    code: int
    minimum: int = 0
    maximum: int = 1023
    invert: bool = False
    deadzone: float = 0.08

    def __post_init__(self) -> None:
        if self.maximum <= self.minimum:
            raise ValueError(f"axis {self.code}: maximum {self.maximum} must exceed minimum {self.minimum}")
        if not 0.0 <= self.deadzone < 1.0:
            raise ValueError(f"axis {self.code}: deadzone {self.deadzone} must be in [0, 1)")

    @classmethod
    def parse(cls, text: str, deadzone: float = 0.08) -> AxisSpec | None:
        """``"-ABS_Y"`` → inverted ABS_Y with the default range; ``""`` → None."""
        text = text.strip()
        if not text:
            return None
        invert = text.startswith("-")
        code = parse_code(text.lstrip("-+"))
        lo, hi = DEFAULT_RANGES.get(code, (0, 1023))
        return cls(code, lo, hi, invert, deadzone)

    def normalise(self, raw: float) -> float:
        """Raw value → [−1, 1] with the deadzone removed (continuous at its edge)."""
        half = 0.5 * (self.maximum - self.minimum)
        x = (raw - self.minimum - half) / half
        x = max(-1.0, min(1.0, x))
        if self.invert:
            x = -x
        mag = abs(x)
        if mag <= self.deadzone:
            return 0.0
        return math.copysign((mag - self.deadzone) / (1.0 - self.deadzone), x)

    def centre(self) -> float:
        return 0.5 * (self.minimum + self.maximum)


@dataclass(frozen=True)
class JoystickMapping:
    """Which axis drives which command component, the dead-man button and the speed limits."""

    linear_x: AxisSpec | None = field(default_factory=lambda: AxisSpec.parse("-ABS_Y"))
    linear_y: AxisSpec | None = None
    angular_z: AxisSpec | None = field(default_factory=lambda: AxisSpec.parse("-ABS_RZ"))
    speed_scale: AxisSpec | None = field(default_factory=lambda: AxisSpec.parse("-ABS_THROTTLE", deadzone=0.0))
    deadman: int | None = CODES["BTN_TRIGGER"]
    max_linear: float = 0.5
    max_lateral: float = 0.5
    max_angular: float = 1.0
    min_scale: float = 0.0

    def axes(self) -> list[AxisSpec]:
        return [a for a in (self.linear_x, self.linear_y, self.angular_z, self.speed_scale) if a is not None]

    def with_ranges(self, ranges: dict[int, tuple[int, int]]) -> JoystickMapping:
        """The same mapping with the raw ranges a device reports for its axes."""

        def fix(a: AxisSpec | None) -> AxisSpec | None:
            if a is None or a.code not in ranges or ranges[a.code][1] <= ranges[a.code][0]:
                return a
            return replace(a, minimum=ranges[a.code][0], maximum=ranges[a.code][1])

        return replace(self, linear_x=fix(self.linear_x), linear_y=fix(self.linear_y),
                       angular_z=fix(self.angular_z), speed_scale=fix(self.speed_scale))


@dataclass(frozen=True)
class StickCommand:
    vx: float = 0.0
    vy: float = 0.0
    wz: float = 0.0
    deadman: bool = False

    @property
    def is_zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.wz == 0.0


def command(mapping: JoystickMapping, axes: dict[int, float], buttons: dict[int, int]) -> StickCommand:
    """The command for the current raw axis values and button states.

    An axis with no value yet counts as centred; the dead-man counts as released until
    pressed. Without a dead-man button configured the stick always drives."""
    held = mapping.deadman is None or buttons.get(mapping.deadman, 0) != 0
    if not held:
        return StickCommand(deadman=False)

    def value(a: AxisSpec | None) -> float:
        return 0.0 if a is None else a.normalise(axes.get(a.code, a.centre()))

    scale = 1.0
    if mapping.speed_scale is not None:
        s = 0.5 * (value(mapping.speed_scale) + 1.0)  # slider [−1, 1] → [0, 1]
        scale = mapping.min_scale + (1.0 - mapping.min_scale) * s
    return StickCommand(
        vx=scale * mapping.max_linear * value(mapping.linear_x),
        vy=scale * mapping.max_lateral * value(mapping.linear_y),
        wz=scale * mapping.max_angular * value(mapping.angular_z),
        deadman=True,
    )
