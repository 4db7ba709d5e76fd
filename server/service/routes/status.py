"""Read-only status: health, scenarios, snapshot, Prometheus metrics."""

from __future__ import annotations

import math

from fastapi import APIRouter
from fastapi.responses import PlainTextResponse

from common.jsonsafe import json_safe
from harness.accuracy import AccuracySummary
from server.pipeline.live_pipeline import SCENARIOS
from server.service.deps import Config, Live
from server.service.http_guard import DROPPED
from server.service.schemas import Health, Machine, Scenarios, Snapshot, error_responses

router = APIRouter(responses=error_responses())


@router.get("/api/health", summary="liveness, loop health and the parts", response_model=Health)
def health(lp: Live, s: Config) -> Health:
    h = lp.health()
    parts = lp.parts()
    idle = lp.idle()
    status = "idle" if idle else "ok" if all(p["running"] for p in parts) else "degraded"
    return Health.model_validate(
        {
            "status": status if lp.running else "error",
            "idle": idle,
            "parts": parts,
            "loop_error": lp.error,
            "viser_port": s.viser_port,
            "viser_running": lp.scene is not None,
            "scenario": lp.scenario,
            **json_safe(h.model_dump()),
            **json_safe(lp.broker_status()),
        }
    )


@router.get("/api/scenarios", summary="the scenarios the loop can run", response_model=Scenarios)
def scenarios(lp: Live) -> Scenarios:
    return Scenarios(current=lp.scenario, scenarios=dict(SCENARIOS))


@router.get(
    "/api/machine",
    summary="the machine the source delivers (axes, spindle, rate, description) and its parts",
    response_model=Machine,
    tags=["machine"],
)
def machine(lp: Live) -> Machine:
    return Machine.model_validate(json_safe(lp.machine_info()))


@router.get(
    "/api/snapshot",
    summary="latest values, truths, knob values, loop health, the monitor's events and status",
    response_model=Snapshot,
    response_model_exclude_unset=True,  # "replay" only while replaying, as the pipeline says
)
def snapshot(lp: Live) -> Snapshot:
    snap = lp.snapshot()
    return Snapshot.model_validate(
        json_safe(
            {
                "pipeline": snap,
                # the models as plain values, so json_safe turns a non-finite float to null
                "health": lp.health().model_dump(),
                "events": lp.recent_events(),
                "status": lp.monitor_status().model_dump(),
            }
        )
    )


def _num(v: float | None) -> float:
    """A gauge's value: NaN where the health has none (JSON null)."""
    return math.nan if v is None else float(v)


@router.get(
    "/metrics",
    response_class=PlainTextResponse,
    summary="Prometheus metrics",
    responses=error_responses(json_route=False),
)
def metrics(lp: Live) -> PlainTextResponse:
    h = lp.health()
    rows = [
        ("cutwatch_loop_lag_seconds", "gauge", "lateness of the last block", _num(h.lag_ms) / 1e3),
        (
            "cutwatch_loop_lag_p99_seconds",
            "gauge",
            "p99 block lateness (last 600 blocks)",
            _num(h.lag_p99_ms) / 1e3,
        ),
        (
            "cutwatch_realtime_factor",
            "gauge",
            "simulated seconds per wall second",
            h.realtime_factor,
        ),
        (
            "cutwatch_speed",
            "gauge",
            "requested speed (0 = paused)",
            0.0 if h.paused else h.speed,
        ),
        ("cutwatch_sim_time_seconds", "gauge", "simulated time", h.sim_t),
        ("cutwatch_ws_clients", "gauge", "connected WebSocket clients", h.clients),
        (
            "cutwatch_ws_dropped_frames_total",
            "counter",
            "frames dropped for slow clients",
            h.dropped_total,
        ),
        ("cutwatch_frames_total", "counter", "frames published", lp.hub.frames_total),
        ("cutwatch_blocks_total", "counter", "blocks simulated", lp.blocks),
        (
            "cutwatch_loop_stalls_total",
            "counter",
            "clock re-anchors after a stall",
            h.stalls,
        ),
    ]
    b = lp.broker_status()
    feed = b.get("feed")
    if feed is not None:
        from server.pipeline.drive_feed import COUNTERS

        rows.append(
            ("cutwatch_feed_connected", "gauge", "broker connection of the drive feed",
             float(bool(feed["connected"])))
        )  # fmt: skip
        rows.append(
            ("cutwatch_feed_buffered_samples", "gauge", "drive samples waiting for the loop",
             feed["buffered_samples"])
        )  # fmt: skip
        for c in COUNTERS:
            rows.append((f"cutwatch_feed_{c}_total", "counter", f"drive feed: {c}", feed[c]))
    for reason, n in DROPPED.items():
        rows.append(
            (f"cutwatch_http_dropped_{reason}_total", "counter",
             f"connections dropped by the HTTP limit {reason}", n)
        )  # fmt: skip
    out = b.get("estimates_out")
    if out is not None:
        rows.append(
            ("cutwatch_estimates_published_total", "counter", "estimates messages published",
             out["published"])
        )  # fmt: skip
    ev_out = b.get("events_out")
    if ev_out is not None:
        rows += [
            ("cutwatch_events_published_total", "counter",
             "events handed to the broker client (cutwatch/<machine>/events)", ev_out["events"]),
            ("cutwatch_commands_published_total", "counter",
             "feed-hold commands handed to the broker client (cutwatch/<machine>/command)",
             ev_out["commands"]),
            ("cutwatch_events_refused_total", "counter",
             "events or commands the broker client refused (its queue full)", ev_out["refused"]),
        ]  # fmt: skip
    ev = lp.events_summary()
    rows += [
        ("cutwatch_events_unacked", "gauge", "monitor events not yet acknowledged", ev["unacked"]),
        ("cutwatch_events_history_errors_total", "counter",
         "monitor events the history could not keep", ev["history_errors"]),
    ]  # fmt: skip
    lines = []
    for name, kind, doc, value in rows:
        lines += [f"# HELP {name} {doc}", f"# TYPE {name} {kind}", f"{name} {_num(value):g}"]
    name = "cutwatch_events_total"
    lines += [f"# HELP {name} monitor events raised, by kind", f"# TYPE {name} counter"]
    lines += [f'{name}{{kind="{k}"}} {n:d}' for k, n in ev["total"].items()]
    acc = lp.accuracy()
    lines += _accuracy_lines(acc)
    return PlainTextResponse(
        "\n".join(lines) + "\n", media_type="text/plain; version=0.0.4; charset=utf-8"
    )


def _accuracy_lines(acc: AccuracySummary) -> list[str]:
    """``cutwatch_force_error_rms{estimate, window, against}``: the rolling rms of each
    force estimate (``against`` = ``truth``, ``q_truth`` (the Q(s)-filtered true force) or
    ``measured_force``; nothing without a reference); the Q filter's own error as the estimate
    ``q_filtered_truth`` against ``truth``. Unknown values (no data yet) are left out."""
    name = "cutwatch_force_error_rms"
    lines = [
        f"# HELP {name} rolling rms error of a force estimate [N m] over the window",
        f"# TYPE {name} gauge",
    ]
    wins = [f"{w:g}s" for w in acc["windows"]]
    truth = acc["mode"] == "truth"
    if acc["mode"] == "none":
        return lines
    series = [(acc["rms"], str(acc["mode"]))]
    if truth:
        series += [(acc["rms_q"], "q_truth"), ({"q_filtered_truth": acc["floor"]}, "truth")]
    for table, against in series:
        for est, values in table.items():
            for w, v in zip(wins, values, strict=True):
                if v is not None and math.isfinite(v):
                    labels = f'estimate="{est}",window="{w}",against="{against}"'
                    lines.append(f"{name}{{{labels}}} {v:.6g}")
    return lines
