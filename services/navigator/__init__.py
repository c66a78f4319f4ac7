"""Navigator: CLF-based nominal goal-reaching controller over a waypoint sequence. The paper's
benchmarks that use it live in :mod:`riskfield.experiments`."""

from .clf import PointMassCLF, UnicycleCLF
from .config import NavigatorConfig
from .navigator import NavCommand, Navigator
from .waypoints import WaypointSequencer

__all__ = [
           "NavCommand",
           "Navigator",
           "NavigatorConfig",
           "PointMassCLF",
           "UnicycleCLF",
           "WaypointSequencer",
]
