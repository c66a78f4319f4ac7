"""Soak: the full simulated stack under the supervising runner (what ``riskfield up`` runs), with
perception SIGKILLed every 60 s and restarted by the runner.

Shows, over ``SOAK_SECONDS`` seconds (default 600; CI runs the full 10 minutes through
``make test``, a developer may run it shorter; not a ``RISKFIELD_*`` name: the services refuse
unknown ones, strict settings):

* memory: each service's RSS (``/proc/<pid>/status`` VmRSS, sampled every 5 s; ``rss_level``)
  grows < 5 % from the two minutes after the 60 s warm-up (their median, ``warm_level``) to the
  second half of the run (its floor, ``end_window``). The router's bound is on what it retains with
  no perception frame in flight (``quiet_growth``: sampled after each kill, once its heap trim ran
  and before the restarted perception is up), since what it forwards is in flight in it and a
  loaded machine holds more in flight. Perception is excluded from the bounds: it is killed every
  60 s, so no incarnation lives past the 60 s warm-up the bound starts from; its RSS is reported
  per incarnation (just before each kill) instead;
* a brake (``SafetyStatus.fallback`` set, ``cmd/safe`` zero) within 0.5 s of every kill;
* motion resumed (no fallback, ``cmd/safe`` moving) after every restart;
* the runner restarted perception once per kill and nothing else.

Measurements go to ``soak.json`` in the test's tmp dir and a table is printed at the end.
Loopback only; the 60 s kill cadence is the scenario, every wait is bounded and event-driven.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml

from riskfield.experiments.navigation import as_waypoints
from riskfield.experiments.scenarios import LOOP, scenario
from riskfield.experiments.stack import publish
from riskfield.protocol import Keys, NavGoal, SafetyStatus, VelocityCommand, decode
from riskfield.services.runtime.processes import (
    ProcessRunner,
    RestartPolicy,
    alive_services,
    client_session,
    free_port,
    wait_until,
)

SOAK_S = float(os.environ.get("SOAK_SECONDS", "600"))
KILL_EVERY_S = 60.0
WARMUP_S = 60.0
SAMPLE_EVERY_S = 5.0
WARM_WINDOW_S = 120.0  # the warm level: the median of the samples over this long after WARMUP_S (``warm_level``)
BRAKE_WITHIN_S = 0.5
RSS_GROWTH = 0.05
MOVING = 0.02  # m/s: cmd/safe faster than this is motion
#: After a kill, the router's RSS is sampled over this window (s): its 1 s heap trim (``heap_trim_s``)
#: has run once without the dead perception's frames, and the restarted one (interpreter, open3d,
#: backend) is not up yet (checked by its liveliness token; a sample with it up is dropped).
QUIET_AFTER_KILL_S = (1.2, 2.0)
SERVICES = ("simulator", "perception", "mapping", "safety-filter", "navigator")


def rss_kb(pid: int) -> int:
    """Resident set size of a live process (kB), from /proc/<pid>/status."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for pid {pid}")


def rss_level(series: list[dict], label: str, t_from: float, t_to: float, q: float = 0.0) -> int | None:
    """The ``q`` quantile (default 0: the floor) of ``label``'s RSS (kB) over the samples in
    ``[t_from, t_to)`` s; None if there are none.

    Why the floor: a process that forwards large messages (the router, every 3.5 MB perception
    frame) holds one or two frames more or less at any instant, depending on what is in flight and
    on how far its loop is from the next heap trim. On this machine that noise is below 1 MB; in one
    CI run the router's samples swung by 4.7 MB (88.3 MB at 60 s, a median of 83.5 MB over the next
    minute), as large as the 5 % bound. What a leak or fragmentation adds stays resident and raises
    every sample, the floor included, so the floor over a minute of samples is the level the growth
    bound compares; the median (``q = 0.5``) and the ceiling are reported beside it."""
    values = sorted(s[label] for s in series if label in s and t_from <= s["t_s"] < t_to)
    return values[min(int(q * len(values)), len(values) - 1)] if values else None


def quiet_growth(kills: list[dict], soak_s: float) -> float | None:
    """Growth of what the router retains with no perception frame in flight: the floor of its quiet
    samples after the kills of the second half (``end_window``) over the first kill's (at the end of
    the warm-up). A load that holds frames in flight longer does not raise a quiet sample; a leak,
    or a session's memory that outlives it, raises every later one (1.5 MB per restart: +6 MB by the
    second half). None without the samples."""
    quiet = [(k["at_s"], k["router_quiet_kb"]) for k in kills if k.get("router_quiet_kb")]
    if not quiet:
        return None
    start = end_window(soak_s)[0]
    late = [kb for at, kb in quiet if at >= start]
    if not late or quiet[0][0] >= start:
        return None
    return (min(late) - quiet[0][1]) / quiet[0][1]


def warm_level(series: list[dict], label: str) -> int | None:
    """The level the growth is measured from: the median of ``label``'s samples over the two
    perception lifetimes after the warm-up (``WARM_WINDOW_S``).

    Not their floor, as the end level is: a floor is robust to what is in flight (it only adds) but
    not to a release. In a run of this test the mapping's floor fell 15 MB (260 → 245 MB) for 40 s
    after the first kill, once, and held 259-267 MB for the rest of the run: the floor of the minute
    after the warm-up read +6.8 % where the level grew 0.6 % (``MAPPING_KB``). The median of two
    lifetimes passes over an excursion of either sign shorter than one lifetime; what a leak adds
    stays, and raises the median too."""
    return rss_level(series, label, WARMUP_S, WARMUP_S + WARM_WINDOW_S, q=0.5)


def end_window(soak_s: float) -> tuple[float, float]:
    """The samples the end level is the floor of: the second half of the run (at least the last
    minute).

    Why several perception lifetimes, not the last minute: in a CI run the router's floor held
    3.5-4.7 MB more (88.1 vs 83.7 MB) from the kill at 540 s to the end, and the same for the
    incarnation started at 360 s, released at the next kill (87.7 MB until 420 s, 84.4 MB after).
    The router holds that for a live perception session: it goes when the session goes, so it is
    bounded, not a leak. The last minute is one incarnation's life and sees such a hold whole;
    the floor over the second half (4-5 incarnations) is what outlives sessions, and a leak of
    1 MB per restart still raises it by ≥ 4 MB, about the 5 % bound."""
    return min(soak_s - KILL_EVERY_S, (WARMUP_S + soak_s) / 2.0), soak_s


class Timeline:
    """Arrival times of the filter's outputs, kept small: (t, fallback) and (t, speed)."""

    def __init__(self, session, keys: Keys):
        self.status: list[tuple[float, str | None]] = []
        self.cmds: list[tuple[float, float]] = []
        self._lock = threading.Lock()

        def on_status(sample) -> None:
            st = decode(sample.payload.to_bytes(), SafetyStatus)
            with self._lock:
                self.status.append((time.monotonic(), st.fallback))

        def on_cmd(sample) -> None:
            c = decode(sample.payload.to_bytes(), VelocityCommand)
            with self._lock:
                self.cmds.append((time.monotonic(), max(abs(c.linear[0]), abs(c.angular[2]))))

        self._subs = [session.declare_subscriber(keys.safety_status, on_status),
                      session.declare_subscriber(keys.cmd_safe, on_cmd)]

    def moving(self) -> bool:
        """The filter passes motion now: its latest status has no fallback, its latest command moves."""
        with self._lock:
            return bool(self.status and self.cmds and self.status[-1][1] is None and self.cmds[-1][1] > MOVING)

    def first_brake_after(self, t: float) -> float | None:
        with self._lock:
            # the brake's zero command goes out just before its status (one session, in order)
            return next((ts for ts, fb in self.status if ts > t and fb not in (None, "slack")), None)

    def first_motion_after(self, t: float) -> float | None:
        with self._lock:
            st = next((ts for ts, fb in self.status if ts > t and fb is None), None)
            if st is None:
                return None
            return next((tc for tc, v in self.cmds if tc >= st and v > MOVING), None)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()


@pytest.mark.timeout(SOAK_S + 600)  # the soak itself, plus start-up and a bounded stop
@pytest.mark.slow
def test_soak_full_stack_with_perception_killed_every_minute(tmp_path: Path, capsys) -> None:
    robot = "t_soak"
    keys = Keys(robot=robot)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(scenario(), sort_keys=False))
    common = ["--robot", robot]
    runner = ProcessRunner(endpoint, keys, log_path=tmp_path / "stack.log",
                           restart=RestartPolicy(backoff_s=0.5, backoff_max_s=5.0, healthy_s=30.0))
    runner.add("router", "router", common)
    runner.add("simulator", "simulator", [*common, "--set", f"scenario={tmp_path / 'scenario.yaml'}"])
    runner.add("perception", "perception", common)
    runner.add("mapping", "mapping", common)
    runner.add("safety-filter", "safety-filter", common)
    runner.add("navigator", "navigator", common)
    code: list[int] = []
    watcher = threading.Thread(target=lambda: code.append(runner.watch(ready_timeout_s=None)), daemon=True)
    t0 = time.monotonic()
    watcher.start()
    kills: list[dict] = []
    rss: dict[str, dict[str, int]] = {}
    perception_rss: list[dict] = []
    series: list[dict] = []
    log = lambda: (tmp_path / "stack.log").read_text()[-4000:]  # noqa: E731
    try:
        with client_session(endpoint, timeout_s=60) as session:
            assert runner.wait_ready(session, timeout_s=180), log()
            line = Timeline(session, keys)
            goal = NavGoal(waypoints=as_waypoints(LOOP), tolerance=0.2, loop=True)
            # The goal is a fifo message: repeated until the filter passes motion (the navigator's
            # subscription may not be matched yet; a repeated identical goal changes nothing).
            assert wait_until(lambda: (publish(session, keys.nav_goal, goal), line.moving())[1], 120.0,
                              period_s=1.0), log()
            pids = {label: runner.children[label].proc.pid for label in ("router", *SERVICES)}
            end = t0 + SOAK_S
            next_kill = t0 + KILL_EVERY_S
            warm = False
            next_sample = t0
            while True:
                now = time.monotonic()
                if not warm and now >= t0 + WARMUP_S:
                    rss = {label: {"warm_kb": rss_kb(pid)} for label, pid in pids.items() if label != "perception"}
                    warm = True
                if now >= end:
                    break
                if now >= next_sample:  # the RSS trend (in soak.json): a plateau or a leak
                    series.append({"t_s": round(now - t0, 1), **{label: rss_kb(c.proc.pid) for label, c in
                                                                 runner.children.items() if c.alive()}})
                    next_sample += SAMPLE_EVERY_S
                if now < next_kill:
                    # The cadence of the scenario; meanwhile nobody but perception may have restarted.
                    time.sleep(min(0.5, next_kill - now, max(0.0, end - now)))
                    others = {label: c.restarts for label, c in runner.children.items() if label != "perception"}
                    assert not any(others.values()), (others, log())
                    continue
                # Kill while the robot moves (the brake must be the kill's doing).
                assert wait_until(line.moving, 60.0), log()
                child = runner.children["perception"]
                victim, n = child.proc.pid, child.restarts
                perception_rss.append({"pid": victim, "rss_kb": rss_kb(victim),
                                       "lived_s": round(time.monotonic() - child.started_at, 1)})
                t_kill = time.monotonic()
                os.kill(victim, signal.SIGKILL)
                quiet: list[int] = []  # the brake's timing is taken from the Timeline meanwhile
                while (now := time.monotonic()) < t_kill + QUIET_AFTER_KILL_S[1]:
                    if now >= t_kill + QUIET_AFTER_KILL_S[0]:
                        quiet.append(rss_kb(pids["router"]))
                    time.sleep(0.1)
                restarted_up = bool(alive_services(session, keys.alive("perception")))
                assert wait_until(lambda t=t_kill: line.first_brake_after(t) is not None, 10.0), log()
                t_brake = line.first_brake_after(t_kill)
                assert wait_until(lambda c=child, n=n: c.restarts == n + 1 and c.alive(), 60.0), log()
                t_restart = child.started_at
                assert wait_until(lambda t=t_restart: line.first_motion_after(t) is not None, 120.0), log()
                t_resume = line.first_motion_after(t_restart)
                kills.append({"at_s": round(t_kill - t0, 1), "brake_ms": round(1e3 * (t_brake - t_kill), 1),
                              "restart_s": round(t_restart - t_kill, 2), "resume_s": round(t_resume - t_kill, 2),
                              "router_quiet_kb": None if restarted_up or not quiet else min(quiet)})
                next_kill += KILL_EVERY_S
            for label, pid in pids.items():
                if label in rss:
                    rss[label]["end_kb"] = rss_kb(pid)
            last = runner.children["perception"]
            perception_rss.append({"pid": last.proc.pid, "rss_kb": rss_kb(last.proc.pid),
                                   "lived_s": round(time.monotonic() - last.started_at, 1)})
            assert all(runner.children[label].proc.pid == pid for label, pid in pids.items() if label != "perception")
            line.close()
    finally:
        runner.request_stop()
        watcher.join(120)
    for r in rss.values():
        r["point_growth_pct"] = round(100.0 * (r["end_kb"] - r["warm_kb"]) / r["warm_kb"], 2)
    for label, r in rss.items():
        r["warm_level_kb"] = warm_level(series, label) or r["warm_kb"]
        r["end_level_kb"] = rss_level(series, label, *end_window(SOAK_S)) or r["end_kb"]
        r["growth_pct"] = round(100.0 * (r["end_level_kb"] - r["warm_level_kb"]) / r["warm_level_kb"], 2)
        for name, q in (("median", 0.5), ("max", 1.0)):
            lo = rss_level(series, label, WARMUP_S, WARMUP_S + WARM_WINDOW_S, q) or r["warm_kb"]
            hi = rss_level(series, label, *end_window(SOAK_S), q) or r["end_kb"]
            r[f"{name}_growth_pct"] = round(100.0 * (hi - lo) / lo, 2)
    report = {"duration_s": SOAK_S, "kill_every_s": KILL_EVERY_S, "rss": rss, "perception_rss": perception_rss,
              "kills": kills, "watch_exit": code,
              "rss_series_kb": series}
    (tmp_path / "soak.json").write_text(json.dumps(report, indent=2) + "\n")
    end_floor = f"floor {end_window(SOAK_S)[0]:.0f}-{SOAK_S:.0f} s"
    table = "\n".join([f"{'service':<14}{'RSS @60 s kB':>14}{'RSS end kB':>12}{'point %':>9}"
                       f"{'median 60-180 s':>16}{end_floor:>17}{'growth %':>10}{'median %':>10}{'max %':>8}",
                       *(f"{label:<14}{r['warm_kb']:>14}{r['end_kb']:>12}{r['point_growth_pct']:>9.2f}"
                         f"{r['warm_level_kb']:>16}{r['end_level_kb']:>17}{r['growth_pct']:>10.2f}"
                         f"{r['median_growth_pct']:>10.2f}{r['max_growth_pct']:>8.2f}" for label, r in rss.items())])
    with capsys.disabled():
        print(f"\nsoak {SOAK_S:.0f} s, perception SIGKILLed every {KILL_EVERY_S:.0f} s ({tmp_path / 'soak.json'})")
        print(table)
        print("perception RSS per incarnation (kB, at its kill / at the end): "
              + ", ".join(f"{p['rss_kb']} ({p['lived_s']:.0f} s)" for p in perception_rss))
        print(f"{'kill at s':>10}{'brake ms':>10}{'restart s':>11}{'resume s':>10}{'router quiet kB':>17}")
        for k in kills:
            print(f"{k['at_s']:>10.1f}{k['brake_ms']:>10.1f}{k['restart_s']:>11.2f}{k['resume_s']:>10.2f}"
                  f"{k['router_quiet_kb'] or '–':>17}")
        quiet = quiet_growth(kills, SOAK_S)
        print("router quiet growth: " + ("–" if quiet is None else f"{100 * quiet:.2f} %"))
    assert code == [0], log()  # every service, perception's last incarnation included, stopped cleanly
    assert len(kills) == max(0, int((SOAK_S - 1e-9) // KILL_EVERY_S))
    assert runner.children["perception"].restarts == len(kills)
    assert all(k["brake_ms"] <= 1e3 * BRAKE_WITHIN_S for k in kills), kills
    if SOAK_S > WARMUP_S:
        # Every service, the router included: it forwards every (large) perception frame, and
        # each restarted perception is a new session with new transport buffers. Without the
        # runtime's heap trimming (``heap_trim_s``, runtime/memory.py) glibc keeps those freed
        # buffers resident and the router grows past the bound here, flat between restarts.
        # The message carries the table and the router's samples: CI prints only the failure.
        router = " ".join(f"{x['t_s']:.0f}:{x['router']}" for x in series if "router" in x)
        others = {label: r for label, r in rss.items() if label != "router" or quiet is None}
        assert all(r["growth_pct"] < 100 * RSS_GROWTH for r in others.values()), f"\n{table}\nrouter kB: {router}"
        # The router by what it retains between perception sessions (the module doc).
        held = [k["router_quiet_kb"] for k in kills]
        assert quiet is None or quiet < RSS_GROWTH, f"\n{table}\nrouter quiet kB: {held}"


# The router's RSS (kB) every 5 s from 5 s to 595 s in a CI run whose last minute alone reads
# +5.2 %: a perception incarnation's hold (360-420 s, 540-600 s) goes at the next kill.
CI_ROUTER_KB = [
    85844, 85880, 85884, 86204, 85916, 85892, 85692, 85948, 85956, 85960, 85976, 85984,
    83748, 84392, 83956, 84612, 84532, 84384, 84628, 83988, 87248, 84584, 83992, 89292,
    84684, 84832, 84152, 84152, 84168, 84152, 84404, 84152, 84148, 84152, 84600, 90524,
    84364, 84844, 84796, 84956, 85052, 85048, 84672, 84716, 85056, 84420, 84868, 90284,
    84436, 84436, 85076, 84648, 84440, 84888, 84396, 84652, 84440, 84440, 84440, 90848,
    84940, 84940, 84496, 84568, 85100, 85108, 85156, 84560, 85064, 85020, 84524, 90844,
    89052, 87792, 87684, 87844, 87684, 87688, 87688, 87688, 87688, 87688, 87688, 87688,
    84440, 84484, 87648, 84440, 84440, 84440, 84444, 84444, 84444, 84444, 84444, 87660,
    84676, 84760, 84648, 84656, 84652, 84608, 86988, 84660, 84660, 84660, 84656, 88384,
    88496, 88500, 88452, 88500, 88500, 88500, 88500, 88504, 88120, 88952, 88504,
]


def _series(label: str, kb: list[int]) -> list[dict]:
    """A recorded RSS series (kB every 5 s from 5 s) as the soak samples it."""
    return [{"t_s": 5.0 * (i + 1), label: v} for i, v in enumerate(kb)]


def _growth(series: list[dict], label: str) -> float:
    """The soak's bound, over a 600 s run: the second half's floor over the warm level."""
    lo = warm_level(series, label)
    return (rss_level(series, label, *end_window(600.0)) - lo) / lo


def _leaky(series: list[dict], label: str, kb_per_restart: int) -> list[dict]:
    """The same run with ``kb_per_restart`` kept at every perception restart."""
    return [{**s, label: s[label] + kb_per_restart * int(s["t_s"] // KILL_EVERY_S)} for s in series]


def test_end_level_passes_a_session_hold_and_fails_a_leak_per_restart() -> None:
    series = _series("router", CI_ROUTER_KB)
    assert _growth(series, "router") < RSS_GROWTH
    last_minute = rss_level(series, "router", 540.0, 600.0) / rss_level(series, "router", 60.0, 120.0) - 1.0
    assert last_minute > RSS_GROWTH  # the last minute alone is one held incarnation: it would fail
    # The same run with 1.5 MB that every restart keeps: the floor of the second half sees it.
    assert _growth(_leaky(series, "router", 1536), "router") > RSS_GROWTH


def test_quiet_growth_passes_a_steady_router_and_fails_a_leak_per_restart() -> None:
    kills = [{"at_s": 60.0 * k, "router_quiet_kb": 84000 + (k % 2) * 300} for k in range(1, 10)]
    assert abs(quiet_growth(kills, 600.0)) < 0.01
    leaky = [{**k, "router_quiet_kb": k["router_quiet_kb"] + 1536 * i} for i, k in enumerate(kills)]
    assert quiet_growth(leaky, 600.0) > RSS_GROWTH  # 1.5 MB kept per restart
    assert quiet_growth([{**k, "router_quiet_kb": None} for k in kills], 600.0) is None
    assert quiet_growth(kills[:4], 600.0) is None  # no kill in the second half


# The mapping's RSS (kB) every 5 s from 5 s to 595 s in the run whose warm floor caught a release
# (``warm_level``): 245 MB from 75 to 115 s, 259-267 MB before and after.
MAPPING_KB = [
    254444, 252300, 259220, 256124, 253912, 254956, 257336, 255552, 254360, 253956, 257760, 259800,
    259936, 260976, 244616, 246348, 244768, 244716, 251204, 244768, 244780, 246396, 250936, 261108,
    259928, 260108, 259784, 258608, 260116, 259496, 260004, 260164, 260132, 260192, 258536, 259944,
    259940, 259420, 260060, 260184, 260108, 259944, 260024, 260676, 260072, 260108, 260036, 260172,
    261328, 261180, 260008, 260136, 260144, 260208, 260228, 259868, 259900, 260060, 260208, 260036,
    260176, 259888, 260084, 260072, 259612, 261336, 263604, 264884, 265152, 264612, 264828, 265816,
    266436, 264480, 267016, 263464, 263460, 261848, 264412, 264288, 264176, 263356, 265304, 263968,
    265540, 264392, 264424, 263900, 264216, 263384, 263548, 264420, 264260, 265560, 265420, 264072,
    263556, 263564, 265592, 265520, 265640, 263572, 263396, 264236, 264064, 263672, 264352, 263628,
    264256, 263504, 264332, 264424, 263244, 263832, 263616, 263432, 263472, 265736, 263928,
]


def test_warm_level_passes_a_release_after_the_warm_up_and_fails_a_leak_per_restart() -> None:
    series = _series("mapping", MAPPING_KB)
    assert _growth(series, "mapping") < 0.01
    floor = rss_level(series, "mapping", WARMUP_S, WARMUP_S + KILL_EVERY_S)
    assert rss_level(series, "mapping", *end_window(600.0)) / floor - 1.0 > RSS_GROWTH  # what the floor read
    # 5 MB that every restart keeps (45 MB by the end, 17 %) raises the median as much as the end
    assert _growth(_leaky(series, "mapping", 5120), "mapping") > RSS_GROWTH
