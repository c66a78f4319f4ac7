"""What crosses the off-board link: the two sites of a deployment, which key crosses which way, and
the per-key traffic a stack puts on it.

The split is the one in docs/deployment.md: the **robot** runs its camera and chassis (in
simulation: the simulator), the safety filter and the bridges; the **server** runs perception,
mapping, the navigator and the operator. Zenoh routes a sample across the routers' link only when a
subscriber on the other side matches it, so a key crosses when its consumers are on the other site.
``sim/truth`` and ``sim/actors`` are simulation artefacts (a real camera has no ground truth): they
are counted apart and never budgeted on the link.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from riskfield.protocol.keys import base_of

#: Robot → server: the robot's sensors and the filter's reports, for perception, mapping, the
#: navigator, the operator and people watching.
UP = "robot→server"
#: Server → robot: the map and the reference commands, for the filter.
DOWN = "server→robot"
LOCAL = "local"
SIM_ONLY = "simulation only"

#: Relative key → the way it goes (``status/*``: the site of the node; see ``direction``).
DIRECTION: dict[str, str] = {
    "camera/image": UP,
    "camera/depth": UP,
    "state": UP,
    "state/relocalise": UP,
    "safety/status": UP,
    "limo/diagnostics": UP,
    "map/esdf": DOWN,
    "map/objects": DOWN,
    "perception/alignment": DOWN,
    "cmd/ref": DOWN,
    "config/risk": DOWN,
    "cmd/safe": LOCAL,
    "perception/frame": LOCAL,
    "map/esdf3d": LOCAL,
    "nav/goal": LOCAL,
    "sim/truth": SIM_ONLY,
    "sim/actors": SIM_ONLY,
}

#: Services by site; a node's ``status/{service}`` crosses to the other site's supervisor/operator.
ROBOT_SERVICES = frozenset({"simulator", "camera", "safety-filter", "limo", "mavlink", "joystick", "router"})

#: The routers' egress downsampling (deploy/zenoh/router.json5 ``downsampling``): key → Hz.
DOWNSAMPLED: dict[str, float] = {"safety/status": 10.0}

#: The link budget for one robot, bytes/s.
BUDGET = {UP: 0.5e6, DOWN: 1.0e6}


def direction(relative: str) -> str:
    if relative.startswith("status/"):
        return UP if relative.split("/", 1)[1] in ROBOT_SERVICES else DOWN
    if relative.startswith("alive/"):
        return LOCAL  # liveliness tokens: declarations, not a stream
    return DIRECTION.get(base_of(relative), LOCAL)


@dataclass
class KeyTraffic:
    """The samples one key carried in a window of ``duration_s``."""

    key: str
    count: int
    bytes: int
    duration_s: float

    @property
    def rate_hz(self) -> float:
        return self.count / self.duration_s

    @property
    def mean_bytes(self) -> float:
        return self.bytes / max(1, self.count)

    @property
    def bytes_per_s(self) -> float:
        return self.bytes / self.duration_s

    @property
    def link_bytes_per_s(self) -> float:
        """What crosses the link: the routers' downsampling caps the rate of some keys."""
        cap = DOWNSAMPLED.get(self.key)
        rate = self.rate_hz if cap is None else min(self.rate_hz, cap)
        return rate * self.mean_bytes


def traffic(counts: Mapping[str, tuple[int, int]], duration_s: float) -> list[KeyTraffic]:
    """``counts``: relative key → (samples, payload bytes) over ``duration_s``; largest first."""
    rows = [KeyTraffic(k, n, b, duration_s) for k, (n, b) in counts.items()]
    return sorted(rows, key=lambda r: -r.bytes_per_s)


def totals(rows: Iterable[KeyTraffic]) -> dict[str, float]:
    """Bytes/s per direction (what the link carries), plus the simulation-only keys apart."""
    out = {UP: 0.0, DOWN: 0.0, LOCAL: 0.0, SIM_ONLY: 0.0}
    for r in rows:
        d = direction(r.key)
        out[d] += r.link_bytes_per_s if d in (UP, DOWN) else r.bytes_per_s
    return out


def within_budget(tot: Mapping[str, float]) -> dict[str, bool]:
    return {d: tot[d] <= BUDGET[d] for d in (UP, DOWN)}
