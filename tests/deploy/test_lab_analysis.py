"""The fault drills' fail-safe invariant (``netns_lab.stale_commands_not_braking``), on made-up
probe events: it is judged on stamps, whatever order the probe heard a map and its commands in."""

from __future__ import annotations

from deploy import netns_lab as lab_mod

S = 1_000_000_000
LIMIT_S, HEARD_SLACK_S = 0.4, 0.15


def esdf(heard: float, stamp_s: float) -> dict:
    return {"t": heard, "k": "esdf", "stamp_ns": int(stamp_s * S)}


def cmd(heard: float, stamp_s: float, moving: bool) -> dict:
    return {"t": heard, "k": "cmd", "stamp_ns": int(stamp_s * S), "linear": [0.3 if moving else 0.0, 0.0, 0.0],
            "angular": [0.0, 0.0, 0.0]}


def check(events: list[dict]) -> tuple[int, list]:
    return lab_mod.stale_commands_not_braking(events, 0.0, 100.0, LIMIT_S, HEARD_SLACK_S)


def test_a_moving_command_on_content_past_the_limit_is_a_violation_and_a_brake_is_not():
    events = [esdf(10.0, 10.0), cmd(10.45, 10.45, moving=False), cmd(10.46, 10.46, moving=True)]
    checked, bad = check(events)
    assert checked == 2 and [v.command["t"] for v in bad] == [10.46]
    assert abs(bad[0].map_age_s - 0.46) < 1e-9


def test_a_map_heard_just_after_the_command_made_from_it_counts():
    """CI's case: the probe heard the command 0.5 s after its previous map and the new map just
    after the command (the map's stamp is 0.38 s before the step that used it)."""
    events = [esdf(10.0, 10.0), cmd(10.5, 10.49, moving=True), esdf(10.52, 10.11)]
    assert check(events) == (0, [])


def test_a_map_the_link_held_back_past_the_command_cannot_have_been_used():
    events = [esdf(10.0, 10.0), cmd(10.5, 10.49, moving=True), esdf(11.2, 10.11)]
    checked, bad = check(events)
    assert checked == 1 and len(bad) == 1


def test_a_command_before_any_map_is_checked_and_one_stamped_before_the_map_ignores_it():
    assert check([cmd(1.0, 1.0, moving=True)])[1]
    events = [esdf(10.0, 10.0), esdf(10.3, 10.3), cmd(10.31, 10.29, moving=True)]
    checked, bad = check(events)  # the step at 10.29 had the 10.0 map only: 0.29 s old, within the limit
    assert (checked, bad) == (0, [])
