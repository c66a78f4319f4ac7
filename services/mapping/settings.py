"""Settings of the mapping node: the runtime's ``NodeSettings`` plus every ``MapperConfig``
field (flat, so ``--set voxel_size=0.1`` or ``RISKFIELD_VOXEL_SIZE`` work) plus the node's own.

Kept apart from ``config.py`` because ``NodeSettings`` pulls in the Zenoh runtime, which
the pure core must not import.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar

from pydantic import Field

from ..runtime.settings import NodeSettings
from .config import MapperConfig


class MappingSettings(NodeSettings, MapperConfig):
    SERVICE: ClassVar[str] = "mapping"

    esdf_rate_hz: Annotated[float, Field(gt=0, le=200)] = 30.0
    """The ESDF is rebuilt and published at most this often, and only after new data: a cap for
    fast cameras, so above the camera rate. At a 10 Hz camera a 10 Hz cap held a frame that came a
    little early (pipeline jitter) back to the node's next timer tick, up to half a period, and the
    publications could lock onto the timer's phase: in the demo perception/frame → ESDF took 76 ms
    at the median and 264 of 950 frames never reached an ESDF; with 30 Hz, 14 ms and 5."""
    esdf3d_key: str = "map/esdf3d"
    """Where the 3-D grid goes when ``output = both`` (relative to ``{prefix}/{robot}/``)."""
    risk_file: Path | None = None
    """A RiskConfig YAML/TOML/JSON file, polled for changes; the ``config/risk`` key overrides it."""
    risk_poll_s: Annotated[float, Field(gt=0)] = 1.0

    def mapper_config(self) -> MapperConfig:
        return MapperConfig(**{k: getattr(self, k) for k in MapperConfig.model_fields})
