"""Who may do what: two roles, their tokens, browser sessions, and the one check.

Roles (``ROLES``, weakest first): ``viewer`` reads (every GET, the dashboard files, the
``/ws`` stream) and ``operator`` also changes (control, knobs, effects, replays,
recordings, uploads, analyses). Each role has its token in the environment:
``CUTWATCH_TOKEN`` the operator's, ``CUTWATCH_VIEW_TOKEN`` the viewer's (optional). With
no token set (loopback only, :func:`server.service.settings.check_security`) everyone is
operator.

API clients send ``Authorization: Bearer <token>``. A browser logs in once
(``POST /api/login`` from the login page) and gets a random session id in an
``HttpOnly``, ``SameSite=Strict`` cookie (:data:`COOKIE`): the token is kept in no page
storage and no URL. Tokens are compared with :func:`secrets.compare_digest`; sessions
live in the process (a restart logs everyone out) and expire after
``CUTWATCH_SESSION_HOURS``.

:func:`check` is the one decision (a role, or the refusal in the service's error shape);
the middleware (``server.service.middleware.Guard``), the route dependencies
(:func:`operator`, :func:`viewer`) and WebSocket routes (:func:`admit`) all call it.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Literal
from urllib.parse import urlsplit

from fastapi import HTTPException
from starlette.requests import HTTPConnection
from starlette.websockets import WebSocket

from server.service.http_errors import ErrorEntry, error
from server.service.settings import Settings, allowed_hosts, token_of

Role = Literal["viewer", "operator"]
ROLES: tuple[Role, ...] = ("viewer", "operator")
#: the session cookie's name
COOKIE = "cutwatch_session"
#: paths answered without credentials (health for probes; the login page and its files)
PUBLIC = frozenset(
    {"/api/health", "/login", "/login.js", "/style.css", "/api/login", "/api/logout",
     "/api/session"}
)  # fmt: skip
#: methods that change nothing (everything else is state-changing: operator, Origin check)
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

AUTH_ALLOWED = "'Authorization: Bearer <token>' or a session cookie (log in at /login)"


@dataclass
class Access:
    """Tokens, sessions and the host allow-list of one app (``app.state.access``)."""

    tokens: dict[Role, str]
    session_s: float
    hosts: list[str]
    _sessions: dict[str, tuple[Role, float]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    @classmethod
    def from_settings(cls, s: Settings) -> Access:
        tokens: dict[Role, str] = {r: token_of(s, r) for r in ROLES if token_of(s, r)}
        return cls(tokens=tokens, session_s=s.session_hours * 3600.0, hosts=allowed_hosts(s))

    @property
    def enabled(self) -> bool:
        """True when a token is set (otherwise every caller is operator)."""
        return bool(self.tokens)

    def role_of_token(self, token: str) -> Role | None:
        """The role whose token ``token`` is (every token compared, in constant time)."""
        found: Role | None = None
        for role, want in self.tokens.items():
            if secrets.compare_digest(token.encode(), want.encode()):
                found = role if found is None or role == "operator" else found
        return found

    def login(self, token: str) -> tuple[str, Role] | None:
        """A new session id and its role for a valid token; None otherwise."""
        role = self.role_of_token(token)
        if role is None:
            return None
        sid = secrets.token_urlsafe(32)
        now = time.monotonic()
        with self._lock:
            for k in [k for k, (_, exp) in self._sessions.items() if exp <= now]:
                del self._sessions[k]
            self._sessions[sid] = (role, now + self.session_s)
        return sid, role

    def logout(self, sid: str) -> None:
        with self._lock:
            self._sessions.pop(sid, None)

    def session_role(self, sid: str) -> Role | None:
        with self._lock:
            got = self._sessions.get(sid)
            if got is None:
                return None
            role, exp = got
            if exp <= time.monotonic():
                del self._sessions[sid]
                return None
            return role

    def role_of(self, conn: HTTPConnection) -> tuple[Role | None, str]:
        """The caller's role and what was found (for the refusal's ``got``)."""
        if not self.enabled:
            return "operator", "no access control (no token set)"
        header = conn.headers.get("authorization")
        if header is not None:
            scheme, _, value = header.partition(" ")
            if scheme.lower() != "bearer" or not value:
                return None, "an Authorization header that is not 'Bearer <token>'"
            role = self.role_of_token(value.strip())
            return role, "a bearer token that does not match"
        sid = conn.cookies.get(COOKIE)
        if sid:
            return self.session_role(sid), "a session that has ended (log in again)"
        return None, "no credentials"


def access_of(conn: HTTPConnection) -> Access:
    """The app's :class:`Access`."""
    a: Access = conn.app.state.access
    return a


def check(conn: HTTPConnection, need: Role) -> tuple[Role | None, int, ErrorEntry | None]:
    """The one access decision: ``(role, 200, None)`` or ``(None, status, error entry)``
    (401 without valid credentials, 403 for a viewer on an operator's request)."""
    role, found = access_of(conn).role_of(conn)
    if role is None:
        msg = f"this request needs {AUTH_ALLOWED}; found {found}"
        return None, 401, error("authorization", AUTH_ALLOWED, found, msg)
    if ROLES.index(role) < ROLES.index(need):
        msg = f"this request needs the {need} role; this session is a {role}"
        return None, 403, error("role", need, role, msg)
    return role, 200, None


def needed_role(method: str) -> Role:
    """Reads are the viewer's, every state-changing method the operator's."""
    return "viewer" if method.upper() in SAFE_METHODS else "operator"


def require(conn: HTTPConnection, need: Role) -> Role:
    """:func:`check`, raising the refusal as an :class:`HTTPException` (routes)."""
    role, status, item = check(conn, need)
    if role is None:
        headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
        raise HTTPException(status, detail=[item], headers=headers)
    return role


def viewer(conn: HTTPConnection) -> Role:
    """Route dependency: a viewer or an operator (HTTP or WebSocket)."""
    return require(conn, "viewer")


def operator(conn: HTTPConnection) -> Role:
    """Route dependency: an operator."""
    return require(conn, "operator")


# ------------------------------------------------------------------ Host and Origin
def host_name(host_header: str) -> str:
    """The name of a Host header without its port (``[::1]:80`` -> ``::1``)."""
    h = host_header.strip().lower()
    if h.startswith("["):
        return h[1:].split("]", 1)[0]
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def host_allowed(conn: HTTPConnection) -> bool:
    """True when the request's Host header names this service (the allow-list)."""
    hosts = access_of(conn).hosts
    return "*" in hosts or host_name(conn.headers.get("host", "")) in hosts


def host_repeated(conn: HTTPConnection) -> bool:
    """True when the request carries more than one Host header (RFC 9112, section 3.2:
    such a request must be answered 400, whatever the first one says)."""
    return sum(1 for k, _ in conn.scope.get("headers", []) if k.lower() == b"host") > 1


#: the port of a scheme when its URL gives none
DEFAULT_PORTS = {"http": 80, "https": 443}
Origin = tuple[str, str, int]


def origin_of(url: str) -> Origin | None:
    """``(scheme, host, port)`` of an origin (``http://a.b:8000``; the port defaulted by
    the scheme), or None when it is not an http(s) origin (another scheme, a path, a user,
    no host, a bad port)."""
    try:
        u = urlsplit(url.strip())
        port = u.port
    except ValueError:
        return None
    scheme = u.scheme.lower()
    if scheme not in DEFAULT_PORTS or not u.hostname or u.username is not None:
        return None
    if u.path not in ("", "/") or u.query or u.fragment:
        return None
    return scheme, u.hostname.lower(), port or DEFAULT_PORTS[scheme]


def own_origin(conn: HTTPConnection) -> Origin | None:
    """This request's own origin: the scheme it arrived by (``ws``/``wss`` as
    ``http``/``https``; behind a TLS proxy, uvicorn takes it from ``X-Forwarded-Proto``
    when the proxy is a trusted address), the Host header's name and port."""
    scheme = {"ws": "http", "wss": "https"}.get(conn.url.scheme, conn.url.scheme)
    return origin_of(f"{scheme}://{conn.headers.get('host', '').strip()}")


def same_origin(conn: HTTPConnection) -> bool:
    """False for a request a browser sends from another origin.

    ``Origin`` (sent by browsers on every cross-origin request, on POSTs and on
    WebSocket upgrades) must name the same scheme, host and port as the request itself
    (:func:`own_origin`); ``null`` (a sandboxed frame, a file) is refused; without
    ``Origin``, ``Sec-Fetch-Site: cross-site`` is refused. A request without either is
    not a browser's cross-site one (curl, scripts): it passes here and still needs its
    credentials.
    """
    origin = conn.headers.get("origin")
    if origin is None:
        return conn.headers.get("sec-fetch-site", "same-origin") in {
            "same-origin", "none", "same-site"
        }  # fmt: skip
    theirs = origin_of(origin)
    return theirs is not None and theirs == own_origin(conn)


def refusal_origin(conn: HTTPConnection) -> ErrorEntry:
    got = conn.headers.get("origin") or conn.headers.get("sec-fetch-site")
    own = own_origin(conn)
    mine = f"{own[0]}://{own[1]}:{own[2]}" if own else "this service's own origin"
    return error(
        "origin",
        f"{mine} (the same scheme, host and port; no cross-site requests)",
        got,
        "a cross-origin browser request may not change anything here (Origin check)",
    )


def refusal_repeated_host(conn: HTTPConnection) -> ErrorEntry:
    found = [v.decode("latin-1")[:100] for k, v in conn.scope["headers"] if k.lower() == b"host"]
    return error(
        "host",
        "exactly one Host header naming this service (RFC 9112, section 3.2)",
        ", ".join(found)[:200],
        f"a request with {len(found)} Host headers is refused, whatever the first one says",
    )


def refusal_host(conn: HTTPConnection) -> ErrorEntry:
    hosts = access_of(conn).hosts
    return error(
        "host",
        "one of " + ", ".join(hosts) + " (CUTWATCH_ALLOWED_HOSTS)",
        conn.headers.get("host", "")[:100],
        "this Host header does not name this service (Host allow-list)",
    )


async def admit(ws: WebSocket, need: Role = "viewer") -> Role | None:
    """Gate of a WebSocket route, before ``accept``: Host, Origin and role checked;
    refused: a 403 handshake answer (the connection never opens) and None."""
    if host_repeated(ws) or not host_allowed(ws) or not same_origin(ws):
        await ws.close(1008)
        return None
    role, _, _ = check(ws, need)
    if role is None:
        await ws.close(1008)
    return role
