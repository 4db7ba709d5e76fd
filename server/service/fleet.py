"""The fleet page: one row per machine, from the estimates every service publishes.

``cutwatch fleet --broker URL`` subscribes to ``cutwatch/+/estimates`` and serves a page
(``/``) with one row per machine — status, force level, wear and remaining life, alarms,
last seen, a link to that machine's dashboard — pushed to the browser over ``/ws`` as
each estimate arrives (no polling delay). A machine that has not published for
``stale_after`` seconds shows as stale until it publishes again. ``/api/fleet`` gives the
same rows as JSON, ``/metrics`` the counters.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import FastAPI, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, PlainTextResponse
from pydantic import BaseModel

from server.pipeline.broker import BrokerConfig, make_client, reason_text
from server.records.drive_wire import WireError, decode_estimates

WEB_DIR = Path(__file__).resolve().parents[2] / "web"
TOPIC = "cutwatch/+/estimates"


class MachineRow(BaseModel):
    """One machine as the fleet page shows it."""

    machine: str
    status: str
    last_seen_s: float
    force: float | None = None
    wear_vb_mm: float | None = None
    remaining_life_min: float | None = None
    alarms: list[str] = []
    dashboard: str | None = None
    source: str | None = None
    messages: int = 0
    #: the drive block's publish time behind this estimate (unix s; for latency)
    drive_wall: float | None = None


class FleetState:
    """The latest estimate of every machine; thread-safe (paho's thread writes)."""

    def __init__(self, stale_after: float = 5.0) -> None:
        self.stale_after = float(stale_after)
        self._lock = threading.Lock()
        self._last: dict[str, tuple[float, dict[str, Any], int]] = {}
        self.malformed = 0
        self.latencies: list[float] = []  # drive block publish -> arrival here [s]
        self.listeners: list[tuple[asyncio.AbstractEventLoop, asyncio.Queue[str]]] = []

    def update(self, payload: bytes, now: float | None = None) -> str | None:
        now = time.time() if now is None else now
        try:
            d = decode_estimates(payload)
            machine = str(d["machine"])
        except (WireError, ValueError, KeyError, TypeError):
            self.malformed += 1
            return None
        with self._lock:
            _, _, count = self._last.get(machine, (0.0, {}, 0))
            self._last[machine] = (now, d, count + 1)
            dw = d.get("drive_wall")
            if isinstance(dw, int | float):
                self.latencies.append(now - float(dw))
                del self.latencies[:-10_000]
        row = json.dumps(self.row(machine, now).model_dump())
        for loop, q in list(self.listeners):
            loop.call_soon_threadsafe(_offer, q, row)
        return machine

    def row(self, machine: str, now: float | None = None) -> MachineRow:
        now = time.time() if now is None else now
        with self._lock:
            seen, d, count = self._last[machine]
        age = now - seen
        alarms = [str(a) for a in d.get("alarms") or []]
        status = "stale" if age > self.stale_after else ("alarm" if alarms else "ok")
        wear = d.get("wear") or {}
        force = d.get("force") or {}
        return MachineRow(
            machine=machine,
            status=status,
            last_seen_s=round(age, 3),
            force=_num(force.get("level")),
            wear_vb_mm=_num(wear.get("VB_mm")),
            remaining_life_min=_num(wear.get("remaining_life_min")),
            alarms=alarms,
            dashboard=d.get("dashboard") if isinstance(d.get("dashboard"), str) else None,
            source=d.get("source") if isinstance(d.get("source"), str) else None,
            messages=count,
            drive_wall=_num(d.get("drive_wall")),
        )

    def rows(self) -> list[MachineRow]:
        now = time.time()
        with self._lock:
            names = sorted(self._last)
        return [self.row(m, now) for m in names]


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _offer(q: asyncio.Queue[str], item: str) -> None:
    if q.full():  # latest wins: a slow page loses rows, never slows the fleet
        with contextlib.suppress(asyncio.QueueEmpty):
            q.get_nowait()
    q.put_nowait(item)


def create_fleet_app(cfg: BrokerConfig, stale_after: float = 5.0) -> FastAPI:
    """The fleet page's app; the broker subscription lives as long as the app."""
    state = FleetState(stale_after)
    status: dict[str, Any] = {"connected": False, "error": ""}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        c: Any = make_client(cfg, client_id=f"cutwatch-fleet-{id(app)}")

        def on_connect(cl: Any, _u: object, _f: object, rc: Any, _p: object = None) -> None:
            if getattr(rc, "is_failure", False):
                status.update(connected=False, error=f"refused: {reason_text(rc)}")
                return
            status.update(connected=True, error="")
            cl.subscribe(TOPIC, qos=0)

        def on_disconnect(_c: object, _u: object, _f: object, rc: Any, _p: object = None) -> None:
            status["connected"] = False

        c.on_connect = on_connect
        c.on_disconnect = on_disconnect
        c.on_message = lambda _c, _u, m: state.update(bytes(m.payload))
        c.connect_async(cfg.host, cfg.port, keepalive=cfg.keepalive)
        c.loop_start()
        app.state.fleet = state
        try:
            yield
        finally:
            c.disconnect()
            c.loop_stop()

    app = FastAPI(title="cutwatch fleet", lifespan=lifespan)

    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(WEB_DIR / "fleet.html")

    @app.get("/fleet.js", include_in_schema=False)
    def script() -> FileResponse:
        return FileResponse(WEB_DIR / "fleet.js", media_type="text/javascript")

    @app.get("/api/fleet", summary="one row per machine")
    def fleet() -> list[MachineRow]:
        return state.rows()

    @app.get("/api/health", summary="broker connection of the fleet page")
    def health() -> dict[str, Any]:
        return {"status": "ok", "broker": cfg.describe(), **status, "machines": len(state.rows())}

    @app.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics")
    def metrics() -> str:
        rows = state.rows()
        lines = [
            f"cutwatch_fleet_machines {len(rows)}",
            f"cutwatch_fleet_stale_machines {sum(r.status == 'stale' for r in rows)}",
            f"cutwatch_fleet_malformed_total {state.malformed}",
            f"cutwatch_fleet_broker_connected {int(status['connected'])}",
        ]
        return "\n".join(lines) + "\n"

    @app.websocket("/ws")
    async def ws(sock: WebSocket) -> None:
        await sock.accept()
        q: asyncio.Queue[str] = asyncio.Queue(maxsize=256)
        entry = (asyncio.get_running_loop(), q)
        state.listeners.append(entry)
        try:
            await sock.send_text(json.dumps({"rows": [r.model_dump() for r in state.rows()]}))
            refreshed = time.monotonic()
            while True:
                # each estimate as it arrives; all rows once a second, so ages and stale
                # states move even while other machines keep the queue busy
                wait = max(0.0, refreshed + 1.0 - time.monotonic())
                try:
                    row = await asyncio.wait_for(q.get(), timeout=wait)
                    await sock.send_text(row)
                except TimeoutError:
                    pass
                if time.monotonic() - refreshed >= 1.0:
                    refreshed = time.monotonic()
                    rows = [r.model_dump() for r in state.rows()]
                    await sock.send_text(json.dumps({"rows": rows}))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            state.listeners.remove(entry)

    return app
