"""The client hub: every WebSocket client's bounded queue, fed by the loop thread.

:class:`Hub` is the set of connected clients; the live loop (or anything that runs on
another thread) hands it frames, ``event`` messages and new ``hello`` messages, and it
wakes the clients' coroutines without ever waiting for one. Each client has a
:class:`ClientQueue`: frames are latest-value-wins (a slow browser loses frames, never
slows the loop, never grows memory), events are never replaced (bounded at
:data:`CLIENT_EVENTS` for a client that reads nothing for a long time), a new hello
discards the frames of the old pipeline. The stream's messages themselves are
:mod:`server.service.protocol`'s.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import threading

from server.errors import CutwatchError

#: event messages waiting for one client (beyond: the oldest dropped and counted)
CLIENT_EVENTS = 1000

__all__ = ["CLIENT_EVENTS", "ClientQueue", "Hub"]


class ClientQueue:
    """Bounded, latest-value-wins frame queue of one WebSocket client.

    Written by the loop thread, read by the client's coroutine; ``dropped`` counts the
    frames pushed out of the full queue since the client last took its frames.
    """

    def __init__(self, maxlen: int, loop: asyncio.AbstractEventLoop) -> None:
        self._frames: collections.deque[str] = collections.deque(maxlen=maxlen)
        self._hello: str | None = None  # a new hello (pipeline changed), never dropped
        # event messages: not latest-value-wins, every one is sent (bounded for a client
        # that reads nothing for a long time), each with the count of frames pushed
        # before it (sent in the order pushed: a frame's status never lags an event)
        self._events: collections.deque[tuple[int, str]] = collections.deque(maxlen=CLIENT_EVENTS)
        self._pushed = 0  # frames pushed since the start
        self.events_dropped = 0
        self._lock = threading.Lock()
        self._loop = loop
        self.event = asyncio.Event()
        self.dropped = 0
        self.dropped_total = 0
        self.closed = False  # the service stops
        self.gone = False  # the client went away

    def push(self, body: str) -> None:
        """Append a frame body (loop thread); the oldest is dropped when full."""
        with self._lock:
            if len(self._frames) == self._frames.maxlen:
                self.dropped += 1
                self.dropped_total += 1
            self._frames.append(body)
            self._pushed += 1

    def push_event(self, body: str) -> None:
        """Append an ``event`` message (loop thread); sent whole, never replaced by a
        later one (only a client that takes nothing for CLIENT_EVENTS events loses
        the oldest, counted in ``events_dropped``)."""
        with self._lock:
            if len(self._events) == self._events.maxlen:
                self.events_dropped += 1
            self._events.append((self._pushed, body))

    def take_all(self) -> tuple[str | None, list[tuple[str, str]], int]:
        """Remove and return a pending new hello (or None), the pending frames and event
        messages in the order they were pushed (``("data", body)``, ``("event",
        body)``), and the frames' drop count since the last take."""
        with self._lock:
            hello, self._hello = self._hello, None
            first = self._pushed - len(self._frames)  # index of the oldest frame kept
            out: list[tuple[str, str]] = []
            i = first
            for mark, body in self._events:
                while i < mark and i < self._pushed:
                    out.append(("data", self._frames[i - first]))
                    i += 1
                out.append(("event", body))
            out += [("data", self._frames[j - first]) for j in range(i, self._pushed)]
            self._frames.clear()
            self._events.clear()
            dropped, self.dropped = self.dropped, 0
            self.event.clear()
        return hello, out, dropped

    def push_hello(self, hello: str) -> None:
        """A new ``hello`` (the pipeline changed): it goes out before any later frame and
        is never dropped; frames still queued belong to the old pipeline and are
        discarded (not counted as dropped: the client could not use them)."""
        with self._lock:
            self._hello = hello
            self._frames.clear()

    def __len__(self) -> int:
        return len(self._frames)


class Hub:
    """The set of connected clients; thread-safe publish from the loop thread."""

    def __init__(self, maxlen: int) -> None:
        self.maxlen = maxlen
        self._clients: set[ClientQueue] = set()
        self._lock = threading.Lock()
        self._aio: asyncio.AbstractEventLoop | None = None
        self.dropped_total = 0
        self.frames_total = 0
        self.closed = False

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Attach the event loop the client coroutines run on."""
        self._aio = loop

    def add(self) -> ClientQueue:
        """Register a client (from its coroutine)."""
        if self.closed:
            raise CutwatchError("the service is shutting down")
        q = ClientQueue(self.maxlen, asyncio.get_running_loop())
        with self._lock:
            self._clients.add(q)
        return q

    def remove(self, q: ClientQueue) -> None:
        """Unregister a client."""
        with self._lock:
            self._clients.discard(q)
            self.dropped_total += q.dropped_total

    @property
    def clients(self) -> int:
        return len(self._clients)

    def dropped(self) -> int:
        """Frames dropped over every client, connected or gone."""
        with self._lock:
            return self.dropped_total + sum(q.dropped_total for q in self._clients)

    def publish(self, body: str) -> None:
        """Hand a frame to every client and wake their coroutines; never blocks on them."""
        with self._lock:
            clients = list(self._clients)
        self.frames_total += 1
        for q in clients:
            q.push(body)
        if clients and self._aio is not None:
            with contextlib.suppress(RuntimeError):  # event loop already closed
                self._aio.call_soon_threadsafe(_wake, clients)

    def publish_event(self, body: str) -> None:
        """Hand an ``event`` message to every client and wake them; never blocks."""
        with self._lock:
            clients = list(self._clients)
        for q in clients:
            q.push_event(body)
        if clients and self._aio is not None:
            with contextlib.suppress(RuntimeError):
                self._aio.call_soon_threadsafe(_wake, clients)

    def publish_hello(self, hello: str) -> None:
        """Hand a new ``hello`` to every client (after a scenario change or a replay)."""
        with self._lock:
            clients = list(self._clients)
        for q in clients:
            q.push_hello(hello)
        if clients and self._aio is not None:
            with contextlib.suppress(RuntimeError):
                self._aio.call_soon_threadsafe(_wake, clients)

    def close(self) -> None:
        """Tell every client coroutine that the service stops."""
        self.closed = True
        with self._lock:
            clients = list(self._clients)
        for q in clients:
            q.closed = True
        if clients and self._aio is not None:
            with contextlib.suppress(RuntimeError):
                self._aio.call_soon_threadsafe(_wake, clients)


def _wake(clients: list[ClientQueue]) -> None:
    for q in clients:
        q.event.set()
