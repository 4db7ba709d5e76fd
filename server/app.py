"""The FastAPI application: REST, WebSocket stream, dashboard files.

Built by :func:`create_app`; the lifespan starts one :class:`~server.live.LiveLoop`
thread and stops it (and tells every WebSocket client) on shutdown. Serve it with one
uvicorn worker: the simulation lives in the process (``cutwatch serve``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import secrets
from collections.abc import AsyncIterator, MutableMapping
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.types import ASGIApp, Receive, Scope, Send

from estimators.errors import ParameterError
from machine.errors import ParameterError as MachineParameterError
from server import protocol
from server.errors import CutwatchError
from server.live import Hub, LiveLoop
from server.pipeline import SCENARIOS, Knob
from server.settings import MAX_SPEED, Settings, check_security

WEB_DIR = Path(__file__).resolve().parent.parent / "web"
UPLOT_DIR = WEB_DIR / "node_modules" / "uplot" / "dist"

Message = MutableMapping[str, Any]


class BodyLimit:
    """ASGI middleware refusing request bodies larger than ``limit`` bytes (413).

    Checks ``Content-Length`` up front and counts streamed (chunked) bodies as they
    arrive.
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                try:
                    size = int(v)
                except ValueError:
                    size = self.limit + 1
                if size > self.limit:
                    await self._reject(send)
                    return
        seen = 0
        rejected = False

        async def counted() -> Message:
            # past the limit: answer 413 ourselves and tell the app the client has gone
            nonlocal seen, rejected
            if rejected:
                return {"type": "http.disconnect"}
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > self.limit:
                    rejected = True
                    await self._reject(send)
                    return {"type": "http.disconnect"}
            return msg

        async def guarded_send(msg: Message) -> None:
            if not rejected:
                await send(msg)

        await self.app(scope, counted, guarded_send)

    async def _reject(self, send: Send) -> None:
        body = json.dumps({"detail": f"request body larger than {self.limit} bytes"}).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})


def _live(request: Request) -> LiveLoop:
    loop: LiveLoop = request.app.state.loop
    return loop


Lp = Annotated[LiveLoop, Depends(_live)]


class Control(BaseModel):
    """Body of ``POST /api/control``."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["pause", "resume", "reset", "speed", "scenario"]
    value: float | None = Field(None, description=f"speed in [0, {MAX_SPEED:g}] (action speed)")
    scenario: str | None = Field(None, description="scenario name (action scenario)")


def _json_safe(v: Any) -> Any:
    if isinstance(v, bool | int | str) or v is None:
        return v
    if isinstance(v, float) and math.isfinite(v):
        return v
    return repr(v)[:80]


def _sanitise(x: Any) -> Any:
    """Non-finite floats anywhere in ``x`` become their repr (JSON has no NaN)."""
    if isinstance(x, float) and not math.isfinite(x):
        return repr(x)
    if isinstance(x, dict):
        return {k: _sanitise(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_sanitise(v) for v in x]
    return x


def _error(field: str, allowed: str, got: Any, msg: str) -> dict[str, Any]:
    return {"field": field, "allowed": allowed, "got": _json_safe(got), "msg": msg}


def _knob_dict(k: Knob) -> dict[str, Any]:
    d: dict[str, Any] = {"value": k.value, "unit": k.unit, "doc": k.doc}
    if isinstance(k.value, bool):
        d["type"] = "bool"
    elif k.choices is not None:
        d["type"] = "choice"
        d["choices"] = list(k.choices)
    else:
        d["type"] = "number"
        d["min"], d["max"] = k.min, k.max
    return d


def _check_knob(name: str, k: Knob, value: Any) -> tuple[Any, dict[str, Any] | None]:
    """Validate one PATCH field against its knob; return (value, None) or (None, error)."""
    if isinstance(k.value, bool):
        if not isinstance(value, bool):
            return None, _error(
                name,
                "true or false",
                value,
                f"{name}: expected true or false, got {_json_safe(value)!r}",
            )
        return value, None
    if k.choices is not None:
        if not isinstance(value, str) or value not in k.choices:
            allowed = "one of " + ", ".join(k.choices)
            return None, _error(
                name, allowed, value, f"{name}: expected {allowed}, got {_json_safe(value)!r}"
            )
        return value, None
    allowed = f"a number in [{k.min:g}, {k.max:g}] {k.unit}".rstrip()
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and math.isfinite(float(value))
    ok = ok and (k.min is None or float(value) >= k.min)
    ok = ok and (k.max is None or float(value) <= k.max)
    if not ok:
        return None, _error(
            name, allowed, value, f"{name}: expected {allowed}, got {_json_safe(value)!r}"
        )
    return float(value), None


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service.

    Parameters
    ----------
    settings
        Configuration; read from the environment (``CUTWATCH_*``) when omitted.

    Raises
    ------
    CutwatchError
        When bound to a non-loopback address without ``CUTWATCH_TOKEN``.
    """
    s = settings if settings is not None else Settings()
    check_security(s)
    if s.scenario not in SCENARIOS:
        raise CutwatchError(f"scenario: expected one of {sorted(SCENARIOS)}, got {s.scenario!r}")
    token = s.token.get_secret_value() if s.token is not None else ""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        hub = Hub(s.client_buffer)
        hub.bind(asyncio.get_running_loop())
        loop = LiveLoop(s, hub)
        app.state.hub, app.state.loop = hub, loop
        if s.viser:
            from server.viser_scene import StageScene

            loop.scene = StageScene(s.host, s.viser_port)
        loop.start()
        try:
            yield
        finally:
            hub.close()
            await asyncio.to_thread(loop.stop)
            if loop.scene is not None:
                loop.scene.stop()

    app = FastAPI(
        title="cutwatch",
        version="0.1.0",
        lifespan=lifespan,
        description="Live cutting-force observers on a simulated machine tool.",
    )
    app.state.settings = s

    def authorised(request: Request) -> None:
        if not token:
            return
        got = request.headers.get("authorization", "")
        if not secrets.compare_digest(got.encode(), f"Bearer {token}".encode()):
            raise _HTTPError(
                401,
                "mutating endpoints need 'Authorization: Bearer <token>' (CUTWATCH_TOKEN)",
                {"WWW-Authenticate": "Bearer"},
            )

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's own 422, with inputs made JSON-safe (a body of Infinity or NaN would
        # otherwise fail to serialise and turn the 422 into a 500)
        return JSONResponse({"detail": _sanitise(jsonable_encoder(exc.errors()))}, status_code=422)

    @app.exception_handler(CutwatchError)
    async def _cutwatch_error(request: Request, exc: CutwatchError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(ParameterError)
    async def _param_error(request: Request, exc: ParameterError) -> JSONResponse:
        return JSONResponse(
            {"detail": [_error(exc.name, exc.expected, exc.got, str(exc))]}, status_code=422
        )

    @app.exception_handler(MachineParameterError)
    async def _machine_param_error(request: Request, exc: MachineParameterError) -> JSONResponse:
        return JSONResponse(
            {"detail": [_error(exc.name, exc.expected, exc.got, str(exc))]}, status_code=422
        )

    @app.exception_handler(_HTTPError)
    async def _http_error(request: Request, exc: _HTTPError) -> JSONResponse:
        return JSONResponse({"detail": exc.detail}, status_code=exc.status, headers=exc.headers)

    @app.get("/api/health", summary="liveness and loop health")
    def health(lp: Lp) -> dict[str, Any]:
        h = lp.health()
        status = "ok" if lp.running else "error"
        return {
            "status": status,
            "loop_error": lp.error,
            "viser_port": s.viser_port,
            "viser_running": lp.scene is not None,
            "scenario": lp.pipeline.scenario,
            **protocol._clean(h),
        }

    @app.get("/api/scenarios", summary="the scenarios the loop can run")
    def scenarios(lp: Lp) -> dict[str, Any]:
        return {"current": lp.pipeline.scenario, "scenarios": dict(SCENARIOS)}

    @app.get("/api/params", summary="live parameters with their allowed ranges")
    def params(lp: Lp) -> dict[str, Any]:
        with lp.lock:
            return {name: _knob_dict(k) for name, k in lp.pipeline.knobs().items()}

    @app.patch(
        "/api/params",
        summary="change live parameters (all or nothing)",
        dependencies=[Depends(authorised)],
        responses={422: {"description": "a field is unknown or out of range; nothing changed"}},
    )
    def patch_params(changes: dict[str, Any], lp: Lp) -> Any:
        with lp.lock:
            knobs = lp.pipeline.knobs()
            errors: list[dict[str, Any]] = []
            clean: dict[str, Any] = {}
            if not changes:
                errors.append(
                    _error(
                        "body",
                        "an object with at least one of " + ", ".join(knobs),
                        changes,
                        "no field given",
                    )
                )
            for name, value in changes.items():
                if name not in knobs:
                    allowed = "one of " + ", ".join(knobs)
                    errors.append(
                        _error(
                            name, allowed, value, f"unknown parameter {name!r}; expected {allowed}"
                        )
                    )
                    continue
                v, err = _check_knob(name, knobs[name], value)
                if err is not None:
                    errors.append(err)
                else:
                    clean[name] = v
            if errors:
                return JSONResponse({"detail": errors}, status_code=422)
            old = {name: knobs[name].value for name in clean}
            try:
                for name, v in clean.items():
                    lp.pipeline.set_knob(name, v)
            except ParameterError:
                for name, v in old.items():
                    with contextlib.suppress(ParameterError):
                        lp.pipeline.set_knob(name, v)
                raise
            return {name: _knob_dict(k) for name, k in lp.pipeline.knobs().items()}

    @app.post(
        "/api/control",
        summary="pause, resume, reset, or set the speed",
        dependencies=[Depends(authorised)],
    )
    def control(body: Control, lp: Lp) -> Any:
        if body.action == "pause":
            lp.pause()
        elif body.action == "resume":
            lp.resume()
        elif body.action == "reset":
            lp.reset()
        elif body.action == "scenario":
            if body.scenario not in SCENARIOS:
                allowed = "one of " + ", ".join(SCENARIOS)
                return JSONResponse(
                    {
                        "detail": [
                            _error(
                                "scenario",
                                allowed,
                                body.scenario,
                                f"scenario: expected {allowed}, got {body.scenario!r}",
                            )
                        ]
                    },
                    status_code=422,
                )
            lp.set_scenario(body.scenario)
        else:
            v = body.value
            if v is None or not math.isfinite(v) or not 0.0 <= v <= MAX_SPEED:
                return JSONResponse(
                    {
                        "detail": [
                            _error(
                                "value",
                                f"a number in [0, {MAX_SPEED:g}]",
                                v,
                                f"speed: expected a number in [0, {MAX_SPEED:g}], "
                                f"got {_json_safe(v)!r}",
                            )
                        ]
                    },
                    status_code=422,
                )
            lp.set_speed(v)
        return {
            "speed": lp.speed,
            "paused": lp.paused,
            "sim_t": lp.pipeline.t,
            "scenario": lp.pipeline.scenario,
        }

    @app.get("/api/snapshot", summary="latest values, truths, knob values and loop health")
    def snapshot(lp: Lp) -> dict[str, Any]:
        with lp.lock:
            snap = lp.pipeline.snapshot()
        out: dict[str, Any] = protocol._clean({"pipeline": snap, "health": lp.health()})
        return out

    @app.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics")
    def metrics(lp: Lp) -> PlainTextResponse:
        h = lp.health()
        rows = [
            ("cutwatch_loop_lag_seconds", "gauge", "lateness of the last block", h["lag_ms"] / 1e3),
            (
                "cutwatch_loop_lag_p99_seconds",
                "gauge",
                "p99 block lateness (last 600 blocks)",
                h["lag_p99_ms"] / 1e3,
            ),
            (
                "cutwatch_realtime_factor",
                "gauge",
                "simulated seconds per wall second",
                h["realtime_factor"],
            ),
            (
                "cutwatch_speed",
                "gauge",
                "requested speed (0 = paused)",
                0.0 if h["paused"] else h["speed"],
            ),
            ("cutwatch_sim_time_seconds", "gauge", "simulated time", h["sim_t"]),
            ("cutwatch_ws_clients", "gauge", "connected WebSocket clients", h["clients"]),
            (
                "cutwatch_ws_dropped_frames_total",
                "counter",
                "frames dropped for slow clients",
                h["dropped_total"],
            ),
            ("cutwatch_frames_total", "counter", "frames published", lp.hub.frames_total),
            ("cutwatch_blocks_total", "counter", "blocks simulated", lp.blocks),
            (
                "cutwatch_loop_stalls_total",
                "counter",
                "clock re-anchors after a stall",
                h["stalls"],
            ),
        ]
        lines = []
        for name, kind, doc, value in rows:
            lines += [f"# HELP {name} {doc}", f"# TYPE {name} {kind}", f"{name} {float(value):g}"]
        return PlainTextResponse(
            "\n".join(lines) + "\n", media_type="text/plain; version=0.0.4; charset=utf-8"
        )

    @app.websocket("/ws")
    async def stream(ws: WebSocket) -> None:
        lp: LiveLoop = ws.app.state.loop
        hub: Hub = ws.app.state.hub
        await ws.accept()
        try:
            q = hub.add()
        except CutwatchError:
            await ws.close(1001, "shutting down")
            return

        async def drain() -> None:
            # read and drop whatever the client sends: its close is seen at once, and the
            # read side keeps flowing (uvicorn pauses reading until the app receives)
            try:
                while (await ws.receive())["type"] != "websocket.disconnect":
                    pass
            except (WebSocketDisconnect, RuntimeError):
                pass
            q.gone = True
            q.event.set()

        reader = asyncio.create_task(drain())
        try:
            with lp.lock:
                chans = [
                    {
                        "name": c.name,
                        "unit": c.unit,
                        "group": c.group,
                        "label": c.label,
                        "grid": protocol.grid_of(c.group),
                    }
                    for c in lp.pipeline.channels()
                ]
            await ws.send_text(
                protocol.hello(
                    chans, lp.pipeline.sample_time, lp.pipeline.scenario, lp.knob_values()
                )
            )
            while True:
                await q.event.wait()
                if q.gone:
                    return
                if q.closed:
                    await ws.close(1001, "server shutting down")
                    return
                frames, dropped = q.take()
                for body in frames:
                    await ws.send_text(protocol.with_dropped(body, dropped))
                    dropped = 0
        except (WebSocketDisconnect, RuntimeError):
            return
        finally:
            reader.cancel()
            hub.remove(q)

    if UPLOT_DIR.is_dir():
        app.mount("/vendor/uplot", StaticFiles(directory=UPLOT_DIR), name="uplot")
    if WEB_DIR.is_dir():
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    app.add_middleware(BodyLimit, limit=s.max_body_bytes)
    return app


class _HTTPError(Exception):
    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        self.status, self.detail, self.headers = status, detail, headers
        super().__init__(detail)
