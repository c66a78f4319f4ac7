"""Latency metrics of a recorded or live stack, shared by the demo report and ``riskfield bench
latency`` / ``bench mapping``: all times are seconds of one wall clock in, milliseconds out.

- command latency = time from a ``cmd/ref`` sample to the next ``cmd/safe`` sample (both as
  received, so both Zenoh hops are included);
- camera → ``cmd/safe`` latency = from a camera frame's stamp (carried by the ESDF built from it:
  its ``header.stamp_ns`` is the newest integrated frame's, the image's stamp) to the first
  ``cmd/safe`` received after that ESDF; ESDF content age = at each ``cmd/safe``, its receive time
  minus the stamp of the newest ESDF received before it (the age of what the map shows, where the
  filter reports the same content age as ``SafetyStatus.esdf_age_ms``, by its own clock); ESDF
  arrival age = at each ``cmd/safe``, its receive time minus the receive time of the newest ESDF
  before it (how long the filter has held the map);
- per stage (``pipeline_stages``): a camera frame's stamp travels unchanged through the image,
  ``perception/frame`` and the ESDF built from it; the time from the stamp to the first arrival
  of each, and how many camera frames never reached it, locate where the content age is spent.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from rich.table import Table

from .timing import timing_stats

#: The keys a camera frame's stamp travels through, in order (the ESDF's is the newest frame's).
STAGES = ("camera/image", "perception/frame", "map/esdf")



def command_latency_ms(ref_t: list[float], safe_t: list[float], since: float = -np.inf) -> list[float]:
    """For each reference sent at or after ``since``, the delay to the next filtered command (ms).
    ``since``: when the filter is up (the demo: every service said so); a command sent before then
    waits for the filter's start, which is not the filter's latency."""
    safe = np.asarray(safe_t)
    out = []
    for t in ref_t:
        if t < since:
            continue
        i = int(np.searchsorted(safe, t, side="left"))
        if i < len(safe):
            out.append((safe[i] - t) * 1e3)
    return out


def camera_to_command_ms(esdf_t: list[float], esdf_stamp: list[float], safe_t: list[float]) -> list[float]:
    """For each new ESDF content (a new stamp), camera stamp → first ``cmd/safe`` after its arrival (ms)."""
    safe = np.asarray(safe_t)
    out, seen = [], set()
    for t, stamp in zip(esdf_t, esdf_stamp, strict=True):
        if stamp in seen:
            continue
        seen.add(stamp)
        i = int(np.searchsorted(safe, t, side="left"))
        if i < len(safe):
            out.append((safe[i] - stamp) * 1e3)
    return out


def content_age_ms(esdf_t: list[float], esdf_stamp: list[float], safe_t: list[float]) -> list[float]:
    """At each ``cmd/safe``: its time minus the newest stamp among the ESDFs received before it (ms)."""
    if not esdf_t:
        return []
    newest = np.maximum.accumulate(np.asarray(esdf_stamp))
    arrived = np.asarray(esdf_t)
    out = []
    for t in safe_t:
        i = int(np.searchsorted(arrived, t, side="right")) - 1
        if i >= 0:
            out.append((t - newest[i]) * 1e3)
    return out


def arrival_age_ms(esdf_t: list[float], safe_t: list[float]) -> list[float]:
    """At each ``cmd/safe``: its time minus the arrival of the newest ESDF received before it (ms):
    the content age with every ESDF stamped by its arrival."""
    return content_age_ms(esdf_t, esdf_t, safe_t)


def content_age_from_image_ms(esdf: list[tuple[float, float]], images: list[tuple[float, float]],
                              safe_t: list[float]) -> list[float]:
    """The content age at each ``cmd/safe`` (:func:`content_age_ms`) counted from the publication of
    the newest image in the ESDF instead of its camera stamp: what the nodes after the camera add.
    A real camera's driver publishes within milliseconds of capture; the simulated camera renders
    in between, on the CPU the nodes share."""
    published = first_arrivals(images)
    known = [(t, published[s]) for t, s in esdf if s in published]
    return content_age_ms([t for t, _ in known], [p for _, p in known], safe_t)


def first_arrivals(arrivals: list[tuple[float, float]]) -> dict[float, float]:
    """Header stamp → the first receive time of a message carrying it (a re-publication is not news)."""
    out: dict[float, float] = {}
    for t, stamp in arrivals:
        if stamp not in out or t < out[stamp]:
            out[stamp] = t
    return out


def pipeline_stages(stamped: dict[str, list[tuple[float, float]]],
                    order: tuple[str, ...] = STAGES) -> dict[str, dict[str, Any]]:
    """Per stage of ``order``: the time from each camera stamp to its first arrival there (ms), the
    hop from the previous stage (ms) and how many of the first stage's stamps never got there.

    .. math::  \\ell_k(s) = t_k(s) - s, \\qquad h_k(s) = t_k(s) - t_{k-1}(s)

    with :math:`t_k(s)` the first arrival at stage :math:`k` of a message stamped :math:`s`. A later
    stage's stamps outside the first stage's range (start-up, shutdown) are left out of the times;
    the last frames before a shutdown can count as skipped."""
    firsts = [first_arrivals(stamped.get(k, [])) for k in order]
    origin = firsts[0]
    lo, hi = (min(origin), max(origin)) if origin else (0.0, -1.0)
    out: dict[str, dict[str, Any]] = {}
    for k, key in enumerate(order):
        here = firsts[k]
        since = [(t - s) * 1e3 for s, t in here.items() if lo <= s <= hi]
        hop = [] if k == 0 else [(t - firsts[k - 1][s]) * 1e3 for s, t in here.items() if s in firsts[k - 1]]
        out[key] = {"from_camera_ms": since, "hop_ms": hop, "n": len(since),
                    "skipped": sum(1 for s in origin if s not in here)}
    return out


#: The nodes' own timing of each stage's work, from their status snapshots: label → (service, stat).
STAGE_WORK = {"simulator render": ("simulator", "render_ms"),
              "perception: stamp → processing starts": ("perception", "start_age_ms"),
              "perception process": ("perception", "process_ms"),
              "mapping: stamp → frame arrives": ("mapping", "frame_arrival_age_ms"),
              "mapping: frame arrives → handled (queue, decode)": ("mapping", "frame_wait_ms"),
              "mapping integrate": ("mapping", "integrate_ms"), "mapping ESDF update": ("mapping", "total_ms"),
              "mapping ESDF update: occupancy (decay, solid fill)": ("mapping", "occupancy_ms"),
              "mapping ESDF update: the 2-D slice": ("mapping", "esdf2d_ms"),
              "mapping: stamp → ESDF published": ("mapping", "esdf_content_age_ms")}


def latency_summary(stamped: dict[str, list[tuple[float, float]]], safe_t: list[float],
                    filter_age_ms: list[float] | None = None,
                    node_extra: dict[str, dict[str, list[float]]] | None = None) -> dict[str, Any]:
    """The end-to-end figures (camera → ``cmd/safe``, ESDF content and arrival age at ``cmd/safe``)
    and the per-stage split, from (receive time, stamp) per ``STAGES`` key and ``cmd/safe`` receive
    times (seconds, one clock); shared by the demo report and ``riskfield bench latency``."""
    esdf = stamped.get("map/esdf", [])
    esdf_t, esdf_s = [t for t, _ in esdf], [s for _, s in esdf]
    stages = pipeline_stages(stamped)
    extra = node_extra or {}
    return {
        "camera_to_cmd_safe_ms": timing_stats(camera_to_command_ms(esdf_t, esdf_s, safe_t)),
        "esdf_content_age_ms": timing_stats(content_age_ms(esdf_t, esdf_s, safe_t)),
        "esdf_arrival_age_ms": timing_stats(arrival_age_ms(esdf_t, safe_t)),
        "esdf_content_age_from_image_ms": timing_stats(
            content_age_from_image_ms(esdf, stamped.get(STAGES[0], []), safe_t)),
        "esdf_age_ms": timing_stats(filter_age_ms or []),
        "stages": {k: {"from_camera_ms": timing_stats(v["from_camera_ms"]), "hop_ms": timing_stats(v["hop_ms"]),
                       "n": v["n"], "skipped": v["skipped"]} for k, v in stages.items()},
        "work_ms": {label: timing_stats(extra.get(svc, {}).get(name, [])) for label, (svc, name) in STAGE_WORK.items()},
    }


def latency_table(lat: dict[str, Any], title: str = "Camera frame → safe command, per stage") -> Table:
    """The table of ``latency_summary``: medians / p99 in ms."""
    def mp(s: dict[str, float] | None) -> str:
        return "–" if s is None else f"{s['median']:.1f} / {s['p99']:.1f}"

    t = Table(title=title, caption="node: the nodes' own timings, sampled by their 1 Hz status snapshots")
    for col in ("stage", "from camera stamp ms (p50 / p99)", "hop ms (p50 / p99)", "camera frames skipped"):
        t.add_column(col)
    for key, row in lat["stages"].items():
        t.add_row(f"→ {key} arrives", mp(row["from_camera_ms"]), mp(row["hop_ms"]), str(row["skipped"]))
    t.add_row("→ first cmd/safe after that ESDF", mp(lat["camera_to_cmd_safe_ms"]), "", "")
    t.add_row("ESDF content age at cmd/safe (now − stamp)", mp(lat["esdf_content_age_ms"]), "", "")
    t.add_row("ESDF content age at cmd/safe from the image's publication",
              mp(lat.get("esdf_content_age_from_image_ms")), "", "")
    t.add_row("ESDF content age, the filter's status", mp(lat["esdf_age_ms"]), "", "")
    t.add_row("ESDF arrival age at cmd/safe", mp(lat["esdf_arrival_age_ms"]), "", "")
    for label, s in lat["work_ms"].items():
        t.add_row(f"node: {label}", "", mp(s), "")
    return t
