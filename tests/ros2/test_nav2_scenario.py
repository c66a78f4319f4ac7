"""A Nav2-style scenario with no ROS installed: the keys zenoh-bridge-ros2dds would serve, over
a real router on loopback, with the real safety filter in its own process.

velocity_smoother → CDR TwistStamped on ``{ns}/cmd_vel_smoothed`` → ros2-bridge → ``cmd/ref`` →
safety-filter (an ESDF of a wall) → ``cmd/safe`` → ros2-bridge → CDR TwistStamped on ``{ns}/cmd_vel``.
Odometry in ``odom`` reaches the filter only through a ``map → odom`` transform.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from riskfield.protocol import EsdfGrid, NodeStatus, RobotState, SafetyStatus, VelocityCommand
from riskfield.services.fields import AnalyticField, to_esdf, to_grid_message
from riskfield.services.geometry.shapes import Plane
from riskfield.services.ros2_bridge.messages import Odometry, RosCodec, Transform
from riskfield.testing import (
    Collector,
    ServiceProcess,
    client_config,
    client_session,
    put,
    wait_alive,
    wait_until,
)

ROBOT, NS = "t_nav2", "t_nav2_ns"
GROUPS = ["high", "mid", "low"]
V_REF = 0.5
MAP_T_ODOM = (0.5, 0.0, 0.0)  # the odom origin sits 0.5 m along the map's x axis


def wall() -> EsdfGrid:
    """A wall (low-risk structure) at x = 1.5 m in the map frame: d = 1.5 − x."""
    plane = AnalyticField(Plane.through([1.5, 0.0, 0.0], [-1.0, 0.0, 0.0], label=3), groups=GROUPS)
    return to_grid_message(to_esdf(plane, [-1, -1, 0], [2, 1, 0], 0.05, planar=True))


class Nav2:
    """What the ROS side would publish through zenoh-bridge-ros2dds: the smoothed controller
    output, wheel odometry and (when switched on) AMCL's map → odom."""

    def __init__(self, session, codec: RosCodec):
        self.session, self.codec = session, codec
        self.odom_x = -1.3  # odom frame: map x = odom x + 0.5
        self.tf_on = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.esdf = wall()

    def _run(self) -> None:
        k = 0
        while not self._stop.is_set():
            now = time.time_ns()
            if k % 2 == 0:
                self.esdf.header.stamp_ns = now  # a live mapper's map: the filter judges content age
                put(self.session, f"rf/{ROBOT}/map/esdf", self.esdf)
            if self.tf_on:
                self.session.put(f"{NS}/tf", self.codec.encode_tf([Transform("map", "odom", MAP_T_ODOM,
                                                                             (0, 0, 0, 1), now)]))
            self.session.put(f"{NS}/odom", self.codec.encode_odometry(Odometry(
                now, "odom", "base_link", (self.odom_x, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0),
                (0.0, 0.0, 0.0))))
            ref = VelocityCommand(linear=(V_REF, 0, 0), angular=(0, 0, 0), source="nav2")
            self.session.put(f"{NS}/cmd_vel_smoothed", self.codec.encode_twist(ref, "TwistStamped", now, "base_link"))
            k += 1
            time.sleep(0.04)

    def __enter__(self) -> Nav2:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)


def test_nav2_cmd_vel_through_the_safety_filter(router_endpoint):
    codec = RosCodec("jazzy")
    bridge_args = ["--robot", ROBOT, "--set", f"namespace={NS}", "--set", "cmd_in_type=TwistStamped",
                   "--set", "cmd_out_type=TwistStamped", "--set", "status_period_s=0.1"]
    with ServiceProcess("safety-filter", router_endpoint, ["--robot", ROBOT]) as sf, \
            ServiceProcess("ros2-bridge", router_endpoint, bridge_args) as bridge, \
            client_session(router_endpoint) as s:
        assert wait_alive(s, f"rf/{ROBOT}/alive/safety-filter"), sf.output
        assert wait_alive(s, f"rf/{ROBOT}/alive/ros2-bridge"), bridge.output
        out = Collector(s, f"{NS}/cmd_vel")
        grids = Collector(s, f"{NS}/riskfield/costmap")
        diags = Collector(s, f"{NS}/diagnostics")
        states = Collector(s, f"rf/{ROBOT}/state", RobotState)
        refs = Collector(s, f"rf/{ROBOT}/cmd/ref/**", VelocityCommand)
        safety = Collector(s, f"rf/{ROBOT}/safety/status", SafetyStatus)
        status = Collector(s, f"rf/{ROBOT}/status/ros2-bridge", NodeStatus)

        def mismatches() -> float:
            return status.items[-1].extra.get("state_frame_mismatch", 0.0) if status.items else 0.0

        def latest_v() -> float | None:
            if not out.items:
                return None
            lin, _, frame = codec.decode_twist(out.items[-1], "TwistStamped")
            assert frame == "base_link"
            return lin[0]

        with Nav2(s, codec) as nav2:
            # 1. Odometry in "odom", ESDF in "map", no map → odom: refused and counted, never mixed.
            assert wait_until(lambda: mismatches() >= 5, 20), bridge.output
            assert not states.items
            assert wait_until(lambda: bool(safety.items) and safety.items[-1].fallback == "no_state", 20)
            assert wait_until(lambda: latest_v() == 0.0, 20)
            assert "odometry frame 'odom' is not the map frame 'map'" in bridge.output
            assert refs.wait(1)[-1].source == "ros2/nav" and refs.items[-1].linear == (V_REF, 0, 0)

            # 2. AMCL's map → odom arrives: states in the map frame, far from the wall the reference passes.
            nav2.tf_on = True
            assert wait_until(lambda: bool(states.items), 20), bridge.output
            st = states.items[-1]
            assert st.header.frame_id == "map" and st.position[0] == -1.3 + MAP_T_ODOM[0]
            assert wait_until(lambda: (latest_v() or 0.0) > 0.95 * V_REF, 20), (safety.items[-1:], sf.output[-1500:])
            v_far = latest_v()

            # 3. Near the wall (look-ahead point 0.35 m from it) the command out is slowed.
            nav2.odom_x = 0.4  # map x = 0.9
            assert wait_until(lambda: bool(states.items) and states.items[-1].position[0] == 0.9, 20)
            assert wait_until(lambda: bool(safety.items) and safety.items[-1].intervening
                              and safety.items[-1].fallback is None, 20)
            out.clear()
            assert wait_until(lambda: len(out.items) >= 5, 20)
            v_near = [codec.decode_twist(b, "TwistStamped")[0][0] for b in out.items[-5:]]
            assert all(0.0 <= v < 0.8 * v_far for v in v_near), (v_far, v_near)

            # The safety status reaches /diagnostics as a WARN while the filter intervenes.
            assert wait_until(lambda: any(codec.decode(d, "diagnostic_msgs/msg/DiagnosticArray").status[0].level == 1
                                          for d in diags.items), 20)

        # 4. The costmap decodes with rosbags; its lethal cells are exactly the ESDF's cells with d ≤ 0.
        grid = codec.ts.deserialize_cdr(grids.wait(1)[-1], "nav_msgs/msg/OccupancyGrid")
        esdf = nav2.esdf
        nx, ny, _ = esdf.shape
        assert (grid.info.width, grid.info.height, grid.header.frame_id) == (nx, ny, "map")
        cells = np.asarray(grid.data).reshape(ny, nx).T
        d = esdf.distance[:, :, 0]
        assert (d <= 0).any() and (d > 0).any()
        np.testing.assert_array_equal(cells == 100, d <= 0)
        assert grid.info.origin.position.x == esdf.origin[0] - esdf.voxel_size / 2

        assert bridge.stop() == 0 and sf.stop() == 0
        for c in (out, grids, diags, states, refs, safety, status):
            c.close()


def test_static_map_to_odom_reaches_a_bridge_started_later(router_endpoint):
    """/tf_static is TRANSIENT_LOCAL: zenoh-bridge-ros2dds keeps it in an AdvancedPublisher's cache,
    and the riskfield bridge, started after it was published, still receives it."""
    import zenoh
    import zenoh.ext as zext

    robot, ns = "t_nav2_static", "t_nav2_static_ns"
    codec = RosCodec("humble")
    cfg = client_config(router_endpoint)
    cfg.insert_json5("timestamping", '{"enabled": true}')  # an AdvancedPublisher's cache needs timestamps
    with zenoh.open(cfg) as s:
        static_pub = zext.declare_advanced_publisher(s, f"{ns}/tf_static", cache=zext.CacheConfig(max_samples=10),
                                                     publisher_detection=True)
        static_pub.put(codec.encode_tf([Transform("map", "odom", (2.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))]))
        args = ["--robot", robot, "--set", f"namespace={ns}", "--set", "ros_distro=humble",
                "--set", "status_period_s=0.1"]
        with ServiceProcess("ros2-bridge", router_endpoint, args) as bridge:
            assert wait_alive(s, f"rf/{robot}/alive/ros2-bridge"), bridge.output
            states = Collector(s, f"rf/{robot}/state", RobotState)
            status = Collector(s, f"rf/{robot}/status/ros2-bridge", NodeStatus)
            assert wait_until(lambda: bool(status.items) and status.items[-1].extra.get("tf_static_received", 0) >= 1,
                              20), bridge.output
            odom = codec.encode_odometry(Odometry(time.time_ns(), "odom", "base_link", (0.5, 0.0, 0.0),
                                                  (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
            s.put(f"{ns}/odom", odom)
            st = states.wait(1)[0]
            assert st.header.frame_id == "map" and st.position == (2.5, 1.0, 0.0)
            # A put on a key expression that only matches the odometry key is not served.
            s.put(f"{ns}/*", odom)
            assert wait_until(lambda: status.items[-1].extra.get("wildcard_dropped", 0) >= 1, 20), bridge.output
            assert len(states.items) == 1
            assert bridge.stop() == 0
            states.close()
            status.close()
        static_pub.undeclare()
