"""The FastAPI application: REST, WebSocket stream, dashboard files.

Built by :func:`create_app`; the lifespan starts one :class:`~server.service.loop.LiveLoop`
thread and stops it (and tells every WebSocket client) on shutdown. Serve it with one
uvicorn worker: the simulation lives in the process (``cutwatch serve``).
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import math
import re
import secrets
from collections.abc import AsyncIterator, MutableMapping
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.types import ASGIApp, Receive, Scope, Send

from estimators.errors import ParameterError
from machine.errors import ParameterError as MachineParameterError
from server.errors import CutwatchError
from server.pipeline.live_pipeline import SCENARIOS, Knob
from server.service import protocol
from server.service.loop import Hub, LiveLoop
from server.service.settings import MAX_SPEED, Settings, check_security

WEB_DIR = Path(__file__).resolve().parents[2] / "web"
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
            from server.service.viser_scene import StageScene

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

    # ------------------------------------------------------------------ issue 4 section 7
    @app.get("/residual", response_class=HTMLResponse, summary="residual reports on disk")
    def residual_index() -> HTMLResponse:
        rows = "".join(
            f'<li><a href="/residual/{html.escape(n)}/">{html.escape(n)}</a></li>'
            for n in residual_reports(s.reports_dir)
        )
        body = rows or "<li>none yet: <code>cutwatch residual LOG --out DIR</code></li>"
        return HTMLResponse(
            "<!doctype html><html><head><meta charset='utf-8'><title>cutwatch residual "
            f"reports</title></head><body><h1>Residual reports in "
            f"{html.escape(str(s.reports_dir))}</h1><ul>{body}</ul></body></html>"
        )

    @app.get("/residual/{name}/", summary="one residual report (its report.html)")
    def residual_report(name: str) -> FileResponse:
        return FileResponse(report_file(s.reports_dir, name, "report.html"))

    @app.get("/residual/{name}/report.json", summary="one residual report (its report.json)")
    def residual_report_json(name: str) -> FileResponse:
        return FileResponse(report_file(s.reports_dir, name, "report.json"))

    @app.post(
        "/api/replay",
        summary="replay a two_inertia log through the live observers",
        dependencies=[Depends(authorised)],
    )
    def replay(body: Replay, lp: Lp) -> dict[str, Any]:
        from server.pipeline.live_pipeline import LivePipeline
        from server.pipeline.sources import ReplaySource, open_replay

        log = open_replay(body.path)
        pipe = LivePipeline(seed=s.seed, source=ReplaySource(log))
        lp.set_pipeline(pipe)
        n = len(log["t"])
        return {
            "scenario": "replay",
            "path": str(log.path),
            "samples": n,
            "sample_time": log.sample_time,
            "duration_s": n * log.sample_time,
            "reference_force": "f_ext" in log.columns,
        }

    @app.get("/api/observer-effects", summary="effects installed in the live observer")
    def get_effects(lp: Lp) -> dict[str, Any]:
        with lp.lock:
            return {"observer_effects": _effects_json(lp.pipeline.effects)}

    @app.post(
        "/api/observer-effects",
        summary="install identified effects (report.json path or its observer_effects list)",
        dependencies=[Depends(authorised)],
    )
    def post_effects(body: EffectsBody, lp: Lp) -> dict[str, Any]:
        effects, skipped = parse_effects(body.path, body.observer_effects)
        with lp.lock:
            lp.pipeline.set_observer_effects(effects)
            return {"observer_effects": _effects_json(lp.pipeline.effects), "skipped": skipped}

    @app.delete(
        "/api/observer-effects",
        summary="remove the installed effects",
        dependencies=[Depends(authorised)],
    )
    def delete_effects(lp: Lp) -> dict[str, Any]:
        with lp.lock:
            lp.pipeline.set_observer_effects(())
        return {"observer_effects": []}

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
            await ws.send_text(lp.hello())
            while True:
                await q.event.wait()
                if q.gone:
                    return
                if q.closed:
                    await ws.close(1001, "server shutting down")
                    return
                hello, frames, dropped = q.take()
                if hello is not None:  # the pipeline changed (scenario, replay)
                    await ws.send_text(hello)
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


class Replay(BaseModel):
    """``POST /api/replay``: a measured log on the server's disk."""

    model_config = ConfigDict(extra="forbid")
    path: str = Field(..., min_length=1, max_length=4096, description="two_inertia log (.csv)")


class EffectsBody(BaseModel):
    """``POST /api/observer-effects``: a residual report.json, or its effects list."""

    model_config = ConfigDict(extra="forbid")
    path: str | None = Field(None, max_length=4096, description="a residual report.json")
    observer_effects: list[dict[str, Any]] | None = Field(
        None, description="[{name, shape, coef}] as in report.json"
    )


def _effects_json(effects: Any) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = protocol._clean(
        [{"name": e.name, "side": e.side, "shape": dict(e.shape), "coef": list(e.coef)}
         for e in effects]
    )  # fmt: skip
    return out


#: effect families referenced to the log's time axis (a drift from its t0, a harmonic of
#: its clock's phase); not installed live: the live clock is another one
LOG_TIME_EFFECTS = ("drift", "harmonic")


def parse_effects(
    path: str | None, items: list[dict[str, Any]] | None
) -> tuple[tuple[Any, ...], list[str]]:
    """Effects from a report.json path or an ``observer_effects`` list, and the names of
    those skipped (:data:`LOG_TIME_EFFECTS`).

    Raises
    ------
    CutwatchError
        Neither or both given, unreadable file, or malformed entries.
    ParameterError
        An entry that :class:`estimators.observer_effects.ObserverEffect` refuses.
    """
    from estimators.observer_effects import ObserverEffect

    if (path is None) == (items is None):
        raise CutwatchError("expected one of 'path' (a report.json) or 'observer_effects'")
    if path is not None:
        p = Path(path)
        try:
            rep = json.loads(p.read_text())
        except FileNotFoundError:
            raise CutwatchError(f"{p}: no such file (expected a residual report.json)") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CutwatchError(f"{p}: not a readable JSON report: {exc}") from None
        items = rep.get("observer_effects") if isinstance(rep, dict) else None
        if not isinstance(items, list):
            raise CutwatchError(
                f"{p}: no 'observer_effects' list (expected a report of "
                "'cutwatch residual --kind two_inertia')"
            )
    out = []
    skipped = []
    for i, e in enumerate(items or []):
        shape: Any = e.get("shape", {}) if isinstance(e, dict) else None
        coef: Any = e.get("coef") if isinstance(e, dict) else None
        ok = isinstance(e, dict) and isinstance(e.get("name"), str)
        ok = ok and isinstance(shape, dict) and isinstance(coef, list)
        ok = ok and all(_is_number(v) for v in coef) and all(_is_number(v) for v in shape.values())
        if not ok:
            raise CutwatchError(
                f"observer_effects[{i}]: expected {{'name': str, 'shape': {{str: number}}, "
                f"'coef': [number, ...]}}, got {e!r}"[:300]
            )
        if e["name"] in LOG_TIME_EFFECTS:
            # referenced to the log's own clock: meaningless on the live clock
            skipped.append(e["name"])
            continue
        out.append(ObserverEffect(e["name"], dict(shape), tuple(float(c) for c in coef)))
    return tuple(out), skipped


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


_REPORT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


def residual_reports(root: Path) -> list[str]:
    """Sub-directories of ``root`` holding a report.html, sorted."""
    if not root.is_dir():
        return []
    return sorted(
        d.name
        for d in root.iterdir()
        if _REPORT_NAME.match(d.name) and (d / "report.html").is_file()
    )


def report_file(root: Path, name: str, leaf: str) -> Path:
    """``root/name/leaf``, refusing any name that would leave ``root``.

    Raises
    ------
    _HTTPError
        404 for an unknown or unsafe name (path traversal) or a missing file.
    """
    base = root.resolve()
    if not _REPORT_NAME.match(name) or ".." in name:
        raise _HTTPError(404, f"no residual report named {name!r} (expected a directory name)")
    f = (base / name / leaf).resolve()
    if not f.is_relative_to(base) or not f.is_file():
        raise _HTTPError(404, f"no residual report named {name!r} in {root}")
    return f


class _HTTPError(Exception):
    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        self.status, self.detail, self.headers = status, detail, headers
        super().__init__(detail)
