"""What one ``riskfield demo`` run is asked to do (the CLI's options), read by the run and its report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class DemoConfig:
    out: Path = Path("out/demo")
    live: bool = False
    foxglove: bool = False  # serve the stack live to Foxglove (the `foxglove` service) while it runs
    robot: str = "demo1"
    seed: int = 0
    teleop_push_s: float = 6.0
    laps: float = 1.5
    budget_s: float = 100.0  # the two experiments together, after start-up
    ready_timeout_s: float = 900.0  # the longest start-up waited for, while the services report progress
    quiet_s: float = 120.0  # a service still starting that printed nothing for this long is stuck
    warm_up: bool = True  # compile the services' kernels before starting them (cheap when done)
    robot_radius: float = 0.15
    verbose: bool = False
    perception: str = "sim"  # or "rgbd": the simulator publishes depth, perception poses it by odometry
    phases: dict[str, float] = field(default_factory=dict)
