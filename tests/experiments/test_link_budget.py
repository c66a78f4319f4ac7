"""The link budget's arithmetic (riskfield/experiments/link.py): which way each key goes, what the
routers' downsampling lets through, and the totals the bench checks against the budget."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from riskfield.experiments.link import (
    BUDGET,
    DOWN,
    DOWNSAMPLED,
    LOCAL,
    SIM_ONLY,
    UP,
    direction,
    totals,
    traffic,
    within_budget,
)
from riskfield.protocol import TOPICS

REPO = Path(__file__).resolve().parents[2]


def test_every_key_of_the_contract_has_a_way() -> None:
    assert direction("camera/image") == UP and direction("map/esdf") == DOWN and direction("cmd/ref") == DOWN
    assert direction("sim/truth") == SIM_ONLY and direction("perception/frame") == LOCAL
    assert direction("status/safety-filter") == UP and direction("status/mapping") == DOWN
    assert direction("alive/mapping") == LOCAL
    assert {direction(k) for k in TOPICS} <= {UP, DOWN, LOCAL, SIM_ONLY}


def test_downsampling_caps_what_crosses_and_matches_the_router_config() -> None:
    cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / "router.json5"))
    (rule,) = json.loads(cfg.get_json("downsampling"))
    assert {r["key_expr"].removeprefix("**/"): r["freq"] for r in rule["rules"]} == DOWNSAMPLED
    (row,) = traffic({"safety/status": (500, 500 * 200)}, 10.0)
    assert row.rate_hz == 50 and row.bytes_per_s == pytest.approx(10_000)
    assert row.link_bytes_per_s == pytest.approx(10 * 200)


def test_totals_and_budget() -> None:
    rows = traffic({"camera/image": (100, 100 * 13_000), "map/esdf": (100, 100 * 51_000),
                    "sim/truth": (100, 100 * 3_540_000), "cmd/safe": (500, 500 * 175)}, 10.0)
    assert rows[0].key == "sim/truth"  # largest first
    tot = totals(rows)
    assert tot[UP] == pytest.approx(130_000) and tot[DOWN] == pytest.approx(510_000)
    assert tot[SIM_ONLY] == pytest.approx(35.4e6) and tot[LOCAL] == pytest.approx(8_750)
    assert within_budget(tot) == {UP: True, DOWN: True}
    raw = totals(traffic({"camera/image": (100, 100 * 590_000)}, 10.0))
    assert raw[UP] > BUDGET[UP] and not within_budget(raw)[UP]


def test_a_robot_site_in_the_bench_subscribes_to_what_goes_down_and_nothing_else() -> None:
    from riskfield.experiments.benches.link import down_keys

    keys = [zenoh.KeyExpr(k) for k in down_keys("rf/r1")]

    def covered(rel: str) -> int:
        return sum(k.includes(zenoh.KeyExpr(f"rf/r1/{rel}")) for k in keys)

    for rel in ("map/esdf", "map/objects", "cmd/ref", "cmd/ref/navigator", "config/risk", "status/mapping",
                "status/navigator"):
        assert covered(rel) == 1, rel  # once: a sample reaches the site's session once
    for rel in ("camera/image", "state", "perception/frame", "sim/truth", "status/safety-filter", "status/simulator"):
        assert covered(rel) == 0, rel
