"""``riskfield bench scale``'s closed loop (``scale_core``), short: the aligned map stops the robot where
s = 1 does, the anchored one does not, and the RESULTS.md section is rewritten between its markers."""

from __future__ import annotations

import pytest

from riskfield.experiments import scale_core as C


def test_aligned_stops_like_s1_and_anchored_does_not() -> None:
    rows = C.run_all((1.0, 1.25), (2.0,), seed=1, drift=True)
    summary = C.summarise(rows, 0.0)
    by = {(r["mode"], r["scale"]): r for r in rows}
    aligned, anchored = by[("aligned", 1.25)], by[("anchored", 1.25)]
    assert aligned["stopped"] and abs(aligned["gap_vs_s1"]) <= C.GAP_TOLERANCE
    assert aligned["error_first"] is not None and abs(aligned["error_first"]) < 0.05  # the floor, before moving
    assert aligned["capped_s"] > 0  # the speed was capped until the estimate converged
    assert abs(aligned["scale_error"]) < 0.01 and aligned["scale_sigma"] < 0.01
    # anchored (no alignment): every obstacle (s − 1) × its distance too near, the robot stops short of nothing
    assert anchored["gap"] < by[("anchored", 1.0)]["gap"] - 0.2
    assert summary["gap_target_met"]


def test_the_results_section_is_rewritten_between_its_markers(tmp_path) -> None:
    rows = [{"scale": s, "distance": 3.0, "mode": m, "gap": 0.27, "error_first": 0.01, "error_1m": 0.002,
             "error_1m_true": 0.02, "error_stop": 0.0, "scale_error": 0.001, "scale_sigma": 0.001, "capped_s": 2.0}
            for m in C.MODES for s in (1.0, 1.15)]
    path = tmp_path / "RESULTS.md"
    path.write_text("# results\n\nkept\n")
    C.update_results(path, C.summarise(rows, 1.0))
    C.update_results(path, C.summarise(rows, 2.0))
    text = path.read_text()
    assert text.count(C.RESULTS_BEGIN) == 1 and text.count("## Map scale") == 1 and "kept" in text
    assert "2 s wall" in text and "met" in text


@pytest.mark.parametrize("scale", [0.87, 1.15])
def test_without_drift_the_aligned_map_is_within_a_centimetre_after_a_metre(scale: float) -> None:
    r = C.run(scale, 3.0, "aligned", seed=2, drift=False)
    assert r["error_1m"] is not None and abs(r["error_1m"]) < 0.01
