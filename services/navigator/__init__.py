"""Navigator: CLF-based nominal goal-reaching controller over a waypoint sequence, plus the
paper-reproduction benchmarks (``riskfield bench safety|teleop|navigation``)."""

from .clf import DoubleIntegratorCLF, UnicycleCLF
from .config import NavigatorConfig
from .navigator import NavCommand, Navigator
from .waypoints import WaypointSequencer

__all__ = [
           "DoubleIntegratorCLF",
           "NavCommand",
           "Navigator",
           "NavigatorConfig",
           "UnicycleCLF",
           "WaypointSequencer",
]
