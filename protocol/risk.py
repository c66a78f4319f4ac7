"""The risk configuration: which labels are obstacles, their risk group, its inflation
margin and its CBF gains. One object shared by the mapping service (margins) and the
safety filter (gains); published on ``{prefix}/{robot}/config/risk`` for hot reload.

Defaults follow the paper's benchmark: margins 0.15 / 0.05 / 0.00 m for high / mid / low;
floor and ceiling (and other free surfaces) are never obstacles; walls and all other
structure are obstacles of the low group; ``person`` and ``animal`` are high risk,
``ball`` low. Higher risk also gets smaller class-K gains (earlier, gentler braking).

**The floor.** A configuration shapes how far the robot keeps from what the map holds, never
whether it is there: every label except the free surfaces of ``FREE_LABELS`` (floor, ceiling,
road, grass, …) is an obstacle of at least the last group (the lowest risk; groups go from high
to low), whatever ``default_group`` and ``free_labels`` say. A configuration can raise a label's
group, widen or narrow margins and change gains; ``default_group = None`` or an extra free label
cannot make occupied geometry free space. A configuration that names no obstacle at all
(``default_group`` null and every group's labels empty) is refused outright: it says something
the floor would silently overrule, so it is a mistake or an attack, never a configuration.
"""

from __future__ import annotations

import hashlib
import json
from functools import cached_property
from typing import Annotated, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from . import ade20k
from .messages import Message

Label = Annotated[int, Field(ge=0, le=65535)]
#: 1/s. A first-order gain α lets the robot close a gap h at α·h: at 20/s it may still enter the last
#: 5 cm at 1 m/s, which a LIMO needs 0.33 m to stop from (1.5 m/s²). A larger gain (from a file or the
#: wire) promises a stop no platform here can make, so it is refused, naming the field.
MAX_GAIN = 20.0
Gain = Annotated[float, Field(gt=0, le=MAX_GAIN, allow_inf_nan=False)]


class RiskGroup(BaseModel):
    """One risk group. ``alpha`` is the first-order (or look-ahead) gain; ``alpha1`` and
    ``alpha2`` are the high-order CBF gains of the double integrator."""

    model_config = ConfigDict(extra="ignore")

    name: str
    labels: list[Label] = Field(default_factory=list)
    margin: Annotated[float, Field(ge=0, le=5.0, allow_inf_nan=False)] = 0.0
    alpha: Gain = 1.0
    alpha1: Gain = 2.0
    alpha2: Gain = 1.0


def _labels(*names: str) -> list[int]:
    return [ade20k.index(n) for n in names]


FREE_LABELS = _labels("floor", "ceiling", "rug", "sky", "road", "sidewalk", "grass", "earth", "field", "path",
                      "runway", "land", "dirt track", "sand")
HIGH_LABELS = _labels("person", "animal")
MID_LABELS = _labels("chair", "armchair", "swivel chair", "sofa", "bed", "table", "coffee table", "desk",
                     "stool", "ottoman", "bench", "cabinet", "plant", "lamp", "television receiver", "computer",
                     "monitor", "bicycle", "minibike", "vase", "fan")
LOW_LABELS = _labels("wall", "ball", "box", "door", "column", "bookcase", "shelf", "wardrobe")
_FREE_BY_NATURE = np.asarray(FREE_LABELS, dtype=np.int64)  # the only labels the floor lets be free


class RiskConfig(Message):
    """Label → risk group → (inflation margin, CBF gains). Group ids are 1-based, in order.

    A label listed in no group is an obstacle of ``default_group`` unless it is in
    ``free_labels``; with ``default_group = None`` it is left to the floor (module doc): an
    obstacle of the last group unless it is a free surface (``FREE_LABELS``).
    """

    SCHEMA: ClassVar[str] = "RiskConfig/1"
    model_config = ConfigDict(extra="ignore", arbitrary_types_allowed=True, ignored_types=(cached_property,))

    groups: list[RiskGroup] = Field(
        default_factory=lambda: [
            RiskGroup(name="high", labels=HIGH_LABELS, margin=0.15, alpha=0.6, alpha1=1.2, alpha2=0.36),
            RiskGroup(name="mid", labels=MID_LABELS, margin=0.05, alpha=1.0, alpha1=1.8, alpha2=0.8),
            RiskGroup(name="low", labels=LOW_LABELS, margin=0.0, alpha=1.5, alpha1=2.5, alpha2=1.5),
        ],
        min_length=1,
        max_length=254,
    )
    free_labels: list[Label] = Field(default_factory=lambda: list(FREE_LABELS))
    default_group: str | None = "low"

    @model_validator(mode="after")
    def _consistent(self) -> RiskConfig:
        names = [g.name for g in self.groups]
        if len(set(names)) != len(names):
            raise ValueError(f"group names must be unique: {names}")
        if self.default_group is not None and self.default_group not in names:
            raise ValueError(f"default_group {self.default_group!r} is not one of {names}")
        seen: dict[int, str] = {}
        for g in self.groups:
            for lab in g.labels:
                if lab in seen and seen[lab] != g.name:
                    raise ValueError(f"label {lab} is in groups {seen[lab]!r} and {g.name!r}")
                seen[lab] = g.name
        if self.default_group is None and not seen:
            raise ValueError("a risk configuration with no obstacle labels (default_group null and every group's "
                             "labels empty) would make every obstacle free: refused")
        return self

    @property
    def group_names(self) -> list[str]:
        return [g.name for g in self.groups]

    def group_id(self, name: str) -> int:
        return self.group_names.index(name) + 1

    def group(self, group_id: int) -> RiskGroup | None:
        """The group of a 1-based id; ``None`` for 0 (no obstacle)."""
        return self.groups[group_id - 1] if group_id > 0 else None

    def label_to_group(self) -> np.ndarray:
        """Lookup table over every uint16 label: its group id, 0 for labels that are free. Under
        the floor (module doc): only a label of ``FREE_LABELS`` listed in no group is 0."""
        lut = np.zeros(65536, dtype=np.uint8)
        if self.default_group is not None:
            lut[:] = self.group_id(self.default_group)
            lut[np.asarray(self.free_labels, dtype=np.int64)] = 0
        for gid, g in enumerate(self.groups, start=1):
            lut[np.asarray(g.labels, dtype=np.int64)] = gid
        lifted = lut == 0
        lifted[_FREE_BY_NATURE] = False
        lut[lifted] = len(self.groups)
        return lut

    def below_floor(self) -> list[int]:
        """Labels this configuration alone would make free that the floor keeps obstacles (module
        doc), sorted; empty when the floor changes nothing. Worth a log line where one is applied."""
        declared = np.zeros(65536, dtype=bool)
        if self.default_group is not None:
            declared[:] = True
            declared[np.asarray(self.free_labels, dtype=np.int64)] = False
        for g in self.groups:
            declared[np.asarray(g.labels, dtype=np.int64)] = True
        declared[_FREE_BY_NATURE] = True
        return np.flatnonzero(~declared).tolist()

    def digest(self) -> str:
        """A short hash of the configuration's content (not its header): the same groups, labels,
        margins, gains, free labels and default group give the same digest on every host."""
        body = self.model_dump(mode="json", exclude={"header"})
        text = json.dumps(body, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def margins(self) -> np.ndarray:
        """Inflation margin (m) per group id; index 0 (no group) is 0."""
        return np.array([0.0, *[g.margin for g in self.groups]])
