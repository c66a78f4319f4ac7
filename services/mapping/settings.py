"""Settings of the mapping node: the runtime's ``NodeSettings`` plus every ``MapperConfig``
field (flat, so ``--set voxel_size=0.1`` or ``RISKFIELD_VOXEL_SIZE`` work) plus the node's own.

Kept apart from ``config.py`` because ``NodeSettings`` pulls in the Zenoh runtime, which
the pure core must not import.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar

from pydantic import Field

from ..runtime.continuity import StateGateSettings
from ..runtime.risk_file import RiskStateSettings
from ..runtime.settings import NodeSettings
from .config import REMOVED_SETTINGS, MapperConfig


class MappingSettings(NodeSettings, MapperConfig, StateGateSettings, RiskStateSettings):
    SERVICE: ClassVar[str] = "mapping"
    REMOVED: ClassVar[dict[str, str]] = REMOVED_SETTINGS

    esdf_rate_hz: Annotated[float, Field(gt=0, le=200)] = 30.0
    """The ESDF is rebuilt and published at most this often on average (a token bucket, so a frame
    that comes a little early still goes at once; runtime/rate.py), and only after new data. Under
    the earlier "one per 1/rate since the last" cap, a 10 Hz camera with the then-default 10 Hz held
    early frames back to the node's next timer tick and the publications locked onto the timer's
    phase: in the demo perception/frame → ESDF took 76 ms at the median and 264 of 950 frames
    never reached an ESDF (with a 30 Hz cap, 14 ms and 5)."""
    esdf3d_key: str = "map/esdf3d"
    """Where the 3-D grid goes when ``output = both`` (relative to ``{prefix}/{robot}/``)."""
    risk_file: Path | None = None
    """A RiskConfig YAML/TOML/JSON file, polled for changes; the ``config/risk`` key overrides it."""
    risk_poll_s: Annotated[float, Field(gt=0)] = 1.0
    """How often risk_file is checked for changes."""
    clock_tolerance_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False, description=(
        "how far after this machine's clock a frame or state may be stamped: a later stamp is "
        "refused and counted (future_frames, state_refused_future_state), it would advance the "
        "map's clock and stamp"))] = 0.1
    frame_backlog: Annotated[int, Field(ge=0, le=7)] = 1
    """A tracking frame (outside the keyframe protocol) is skipped as superseded only when more than
    this many newer frames wait behind it. 0 is pure latest-value; 1 lets a pair that arrives back
    to back (a sender catching up, a network burst) both reach the map and the ESDF, one update
    later at most, while a node that cannot keep up still never builds a backlog. With 0, the 3-D
    node fed 30 Hz frames skipped 11 of 290 (`riskfield bench mapping`), though a frame costs it
    11-13 ms."""
    heap_keep_mb: Annotated[int, Field(ge=0, le=2047)] = 256
    """Freed heap the process keeps for the next ESDF update instead of giving it back at every
    ``free`` (``runtime.memory.keep_freed_heap``; 0 = glibc's own policy): each 3-D update frees
    and reallocates about 25 MB of arrays, and taking them fresh from the kernel (5200 page
    faults) made the bench room's update 9.7 ms instead of 7.4 ms. ``heap_trim_s`` still returns
    it all once a second."""

    def mapper_config(self) -> MapperConfig:
        return MapperConfig(**{k: getattr(self, k) for k in MapperConfig.model_fields})
