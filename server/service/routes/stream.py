"""``/ws``: the live stream (a hello, the unacknowledged events, then data frames and
events as they come; see ``server.service.protocol``)."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.errors import CutwatchError
from server.service import protocol
from server.service.hub import Hub
from server.service.loop import LiveLoop

router = APIRouter(tags=["stream"])


@router.websocket("/ws")
async def stream(ws: WebSocket) -> None:
    lp: LiveLoop = ws.app.state.loop
    hub: Hub = ws.app.state.hub
    await ws.accept()
    try:
        q, backlog = lp.add_client()
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
        for body in backlog:  # the events raised before and not yet acknowledged
            await ws.send_text(body)
        while True:
            await q.event.wait()
            if q.gone:
                return
            if q.closed:
                await ws.close(1001, "server shutting down")
                return
            hello, messages, dropped = q.take_all()
            if hello is not None:  # the pipeline changed (scenario, replay)
                await ws.send_text(hello)
            for kind, body in messages:  # frames and events in the order raised
                if kind == "event":  # every one (never dropped)
                    await ws.send_text(body)
                else:
                    await ws.send_text(protocol.with_dropped(body, dropped))
                    dropped = 0
    except (WebSocketDisconnect, RuntimeError):
        return
    finally:
        reader.cancel()
        hub.remove(q)
