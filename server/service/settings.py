"""Settings of the live service, read from the environment (prefix ``CUTWATCH_``).

Examples: ``CUTWATCH_PORT=8001``, ``CUTWATCH_SPEED=0`` (start paused),
``CUTWATCH_HOST=0.0.0.0 CUTWATCH_TOKEN=...`` (any address other than loopback needs a
token of 16 characters at least; see :func:`check_security` and ``server.service.auth``).
"""

from __future__ import annotations

import ipaddress
import math
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import AfterValidator, Field, SecretStr
from pydantic_core import PydanticCustomError
from pydantic_settings import BaseSettings, SettingsConfigDict

from common.errors import ParameterError
from server.errors import CutwatchError
from server.pipeline.live_pipeline import DEFAULT_SCENARIO, SCENARIOS

MAX_SPEED = 1000.0
#: the shortest token accepted (CUTWATCH_TOKEN, CUTWATCH_VIEW_TOKEN)
MIN_TOKEN_CHARS = 16


def _scenario(name: str) -> str:
    if name not in SCENARIOS:
        allowed = ", ".join(SCENARIOS)
        raise PydanticCustomError("scenario", "expected one of {allowed}", {"allowed": allowed})
    return name


def _speed(v: float) -> float:
    if not (math.isfinite(v) and 0.0 <= v <= MAX_SPEED):
        raise PydanticCustomError("speed", "a speed in [0, {hi}]", {"hi": f"{MAX_SPEED:g}"})
    return v


#: the one check of a speed (the setting, ``POST /api/control``)
Speed = Annotated[
    float,
    AfterValidator(_speed),
    Field(description=f"simulated seconds per wall second in [0, {MAX_SPEED:g}] (0 = paused)"),
]
#: the one check of a scenario's name (the setting, ``POST /api/control``)
ScenarioName = Annotated[str, AfterValidator(_scenario)]


class Settings(BaseSettings):
    """Configuration of ``cutwatch serve`` (every field also ``CUTWATCH_<FIELD>``)."""

    model_config = SettingsConfigDict(env_prefix="CUTWATCH_", extra="ignore", validate_default=True)

    host: str = Field(default="127.0.0.1", description="address to bind (loopback by default)")
    port: int = Field(default=8000, ge=1, le=65535, description="HTTP / WebSocket port")
    viser_port: int = Field(
        default=8080,
        ge=1,
        le=65535,
        description="port of the viser 3D view, on 127.0.0.1 only (browsers use /viser/)",
    )
    scenario: ScenarioName = Field(
        default=DEFAULT_SCENARIO,
        description="scenario at start (see /api/scenarios; default: the machining centre)",
    )
    speed: Speed = 1.0
    block_ms: float = Field(default=50.0, ge=1.0, le=1000.0, description="loop block length [ms]")
    frame_hz: float = Field(default=20.0, ge=1.0, le=60.0, description="WebSocket frame rate [Hz]")
    display_points: int = Field(
        default=42, ge=1, le=2000, description="displayed samples per channel per block at 1x"
    )
    ws_deflate: bool = Field(
        default=False,
        description=(
            "offer permessage-deflate on /ws (off: every client would compress the same "
            "frame again, which cost more CPU than the whole stream; see docs/live-service.md)"
        ),
    )
    client_buffer: int = Field(
        default=4, ge=1, le=64, description="frames buffered per client (oldest dropped)"
    )
    max_body_bytes: int = Field(
        default=16384, ge=256, le=1 << 20, description="largest request body accepted [bytes]"
    )
    header_timeout_s: float = Field(
        default=10.0,
        gt=0.0,
        le=300.0,
        description="a request's line and headers must arrive within this time [s] (then 408)",
    )
    body_timeout_s: float = Field(
        default=10.0,
        gt=0.0,
        le=300.0,
        description="longest silence while a request body is due [s] (then 408)",
    )
    body_min_rate: float = Field(
        default=1024.0,
        ge=0.0,
        le=1e9,
        description="slowest average request body accepted past body_timeout_s [bytes/s]",
    )
    max_header_bytes: int = Field(
        default=32768,
        ge=1024,
        le=1 << 20,
        description="largest request line and headers accepted [bytes] (then 431)",
    )
    max_connections_per_client: int = Field(
        default=64,
        ge=1,
        le=100_000,
        description="HTTP connections open at once from one address (then 503)",
    )
    max_lag_s: float = Field(
        default=2.0, gt=0.0, le=60.0, description="lag after which the loop re-anchors its clock"
    )
    token: SecretStr | None = Field(
        default=None,
        description=(
            "the operator's token (changes, acknowledges, uploads, recordings, and every "
            f"read); at least {MIN_TOKEN_CHARS} characters; unset: no access control "
            "(loopback only)"
        ),
    )
    view_token: SecretStr | None = Field(
        default=None,
        description=(
            "the viewer's token (reads and the stream, no changes); needs CUTWATCH_TOKEN; "
            f"at least {MIN_TOKEN_CHARS} characters"
        ),
    )
    allowed_hosts: str = Field(
        default="",
        description=(
            "Host headers answered, comma-separated (e.g. 'cutwatch.shop.lan,10.0.0.5'); "
            "empty: the loopback names when bound to loopback, the bound address and "
            "public_url's host otherwise, any host when bound to 0.0.0.0 or ::"
        ),
    )
    session_hours: float = Field(
        default=12.0, gt=0.0, le=24.0 * 30, description="lifetime of a browser session [h]"
    )
    seed: int = Field(default=0, ge=0, description="seed of the simulation's random generators")
    model: str = Field(
        default="",
        description=(
            "residual reports whose effects the live rigid model of an axis holds "
            "(issue 30 item 4), comma-separated [AXIS=]REPORT.json (without AXIS=: every "
            "axis); their coefficients are identified live with M, Fv, Fc"
        ),
    )
    parts: str = Field(
        default="",
        description=(
            "live parts to add to the pipeline, comma-separated module:attribute (a part "
            "class or factory on the Python path; docs/adding-a-part.md)"
        ),
    )
    viser: bool = Field(default=True, description="start the viser 3D view on viser_port")
    source: Literal["simulator", "mqtt", "opcua"] = Field(
        default="simulator",
        description=(
            "where the measurements come from: the simulated machine, a real machine's "
            "drive blocks on the broker (mqtt_broker, mqtt_machine), or a CNC's OPC UA "
            "server (opcua_url, opcua_nodes; docs/opcua.md)"
        ),
    )
    opcua_url: str | None = Field(
        default=None, description="the CNC's OPC UA server, opc.tcp://host:port[/path]"
    )
    opcua_nodes: Path | None = Field(
        default=None, description="the node map (JSON; `cutwatch opcua browse` starts one)"
    )
    opcua_publishing_s: float | None = Field(
        default=None,
        gt=0.0,
        le=10.0,
        description="the subscription's publishing interval [s] (default: the map's sample "
        "time, at least 0.1 s, a CNC's fastest)",
    )
    opcua_security: str = Field(
        default="best",
        description="best (the strongest of Aes256_Sha256_RsaPss, Aes128_Sha256_RsaOaep, "
        "Basic256Sha256 the server offers), one of them, or None (only when named)",
    )
    opcua_cert: Path | None = Field(default=None, description="the client's certificate")
    opcua_key: Path | None = Field(default=None, description="the client's private key")
    opcua_cert_dir: Path | None = Field(
        default=None,
        description="where a self-signed client certificate is made when opcua_cert is not "
        "given (default: data_dir/opcua)",
    )
    opcua_trust: str = Field(
        default="",
        description="trusted server certificates or folders of them, comma-separated",
    )
    mqtt_broker: str | None = Field(
        default=None,
        description="broker URL mqtt://host[:port] or mqtts://host[:port] (docs/broker.md)",
    )
    mqtt_machine: str = Field(
        default="machine-1", description="machine name: topics cutwatch/<machine>/..."
    )
    mqtt_username: str | None = Field(default=None, description="broker user name")
    mqtt_password: SecretStr | None = Field(default=None, description="broker password")
    mqtt_cafile: Path | None = Field(
        default=None,
        description="CA certificate(s) (PEM) the broker's certificate is checked against (TLS)",
    )
    mqtt_certfile: Path | None = Field(
        default=None,
        description="this service's client certificate (PEM), for a broker that requires one",
    )
    mqtt_keyfile: Path | None = Field(
        default=None, description="the private key of mqtt_certfile, when not in its file"
    )
    mqtt_publish_hz: float = Field(
        default=0.0,
        ge=0.0,
        le=50.0,
        description="estimates published on cutwatch/<machine>/estimates per second (0: off)",
    )
    mqtt_buffer_s: float = Field(
        default=10.0,
        gt=0.0,
        le=600.0,
        description="drive samples buffered from the broker [s]; older ones are dropped",
    )
    public_url: str | None = Field(
        default=None,
        description="this dashboard's URL as others reach it (the fleet page links it)",
    )
    data_dir: Path = Field(
        default=Path("data"),
        description=(
            "the service's data: recordings/, uploads/ and reports/ (made on demand); "
            "replay, analysis and effect installs read files only from here, by name"
        ),
    )
    reports_dir: Path | None = Field(
        default=None,
        description=(
            "the reports area (sub-directories holding residual reports, GET /residual); "
            "default: data_dir/reports"
        ),
    )
    history_url: str | None = Field(
        default=None,
        description=(
            "database of the kept history (monitor events, acknowledgements, tool lives): "
            "a SQLAlchemy URL (e.g. postgresql+psycopg://user@host/cutwatch); default: "
            "SQLite data_dir/history/cutwatch.sqlite; 'none': keep no history"
        ),
    )
    checkpoint_s: float = Field(
        default=10.0,
        ge=0.0,
        le=86_400.0,
        description=(
            "save the pipeline's state to data_dir/state/pipeline.npz this often [wall s] "
            "and at shutdown, and resume from it at start (docs/checkpoints.md); 0: never"
        ),
    )
    block_log: Path | None = Field(
        default=None,
        description=(
            "a file the loop appends one line per block to: the source time of its first "
            "sample and of the sample after its last [s], and the wall time (unix s) the "
            "loop took it (for latency measurements: cutwatch bench monitoring); none: off"
        ),
    )
    record_max_mb: float = Field(
        default=200.0, gt=0.0, le=100_000.0, description="largest recording [MB] (then it stops)"
    )
    record_max_minutes: float = Field(
        default=60.0, gt=0.0, le=10_080.0, description="longest recording [min] (then it stops)"
    )
    upload_max_mb: float = Field(
        default=100.0,
        gt=0.0,
        le=100_000.0,
        description="largest uploaded file [MB] (413 above); also the most a .mat may expand to",
    )
    upload_max_rows: int = Field(
        default=20_000_000, ge=2, description="most data rows of an uploaded CSV log"
    )
    upload_max_columns: int = Field(
        default=64, ge=2, le=10_000, description="most columns of an uploaded CSV log"
    )
    upload_check_mb: int = Field(
        default=1536,
        ge=256,
        le=1 << 20,
        description=(
            "address space of the child process checking an upload [MB] (RLIMIT_AS; the "
            "interpreter with numpy and scipy takes about 450 of it)"
        ),
    )
    upload_check_s: float = Field(
        default=300.0, gt=0.0, le=3600.0, description="longest check of an upload [s]"
    )

    @property
    def reports_area(self) -> Path:
        """Where residual reports live: ``reports_dir`` if set, else ``data_dir/reports``."""
        return self.reports_dir if self.reports_dir is not None else self.data_dir / "reports"

    @property
    def upload_max_bytes(self) -> int:
        return int(self.upload_max_mb * 1e6)


def is_loopback(host: str) -> bool:
    """True if ``host`` is a loopback address or ``localhost`` (parsed by
    :mod:`ipaddress`: ``127.0.0.1.attacker.example`` is a name, not loopback)."""
    h = host.strip().strip("[]")
    if h.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


def _secret(v: SecretStr | None) -> str | None:
    return None if v is None else v.get_secret_value()


def token_of(settings: Settings, role: str) -> str:
    """The token of ``role`` (``operator`` or ``viewer``), "" when unset."""
    v = settings.token if role == "operator" else settings.view_token
    return _secret(v) or ""


def check_token(field: str, value: str | None) -> None:
    """Refuse a token that is set but empty, blank, padded or shorter than the minimum.

    Raises
    ------
    ParameterError
        Naming the variable, what it allows and what was found (the token itself is
        never printed: only its length).
    """
    if value is None:
        return
    allowed = f"at least {MIN_TOKEN_CHARS} characters, no spaces around them"
    if not value.strip():
        raise ParameterError(field, allowed, "an empty or blank value")
    if value != value.strip() or len(value) < MIN_TOKEN_CHARS:
        raise ParameterError(field, allowed, f"a value of {len(value)} characters")


def allowed_hosts(settings: Settings) -> list[str]:
    """The Host header names answered (``["*"]``: any)."""
    if settings.allowed_hosts.strip():
        return [h.strip().lower() for h in settings.allowed_hosts.split(",") if h.strip()]
    if is_loopback(settings.host):
        return ["127.0.0.1", "localhost", "::1"]
    h = settings.host.strip().strip("[]")
    try:
        if ipaddress.ip_address(h).is_unspecified:
            return ["*"]
    except ValueError:
        pass
    out = [h.lower(), "127.0.0.1", "localhost", "::1"]
    if settings.public_url:
        name = urlsplit(settings.public_url).hostname
        if name:
            out.append(name.lower())
    return out


def check_security(settings: Settings) -> None:
    """Refuse to serve on a non-loopback address without a bearer token, and refuse
    malformed tokens (empty, blank, short, a viewer token without an operator one, the
    same token for both roles).

    Raises
    ------
    ParameterError
        A token that is set but not acceptable (named: CUTWATCH_TOKEN or
        CUTWATCH_VIEW_TOKEN).
    CutwatchError
        If ``settings.host`` is not loopback and no token is set.
    """
    op, view = _secret(settings.token), _secret(settings.view_token)
    check_token("CUTWATCH_TOKEN", op)
    check_token("CUTWATCH_VIEW_TOKEN", view)
    if view is not None and op is None:
        raise ParameterError(
            "CUTWATCH_VIEW_TOKEN", "set together with CUTWATCH_TOKEN (the operator's)",
            "a viewer token alone",
        )  # fmt: skip
    if view is not None and view == op:
        raise ParameterError(
            "CUTWATCH_VIEW_TOKEN", "a token other than CUTWATCH_TOKEN", "the operator's token"
        )
    if not is_loopback(settings.host) and not op:
        raise CutwatchError(
            f"binding to {settings.host!r} (not loopback) requires a bearer token: set "
            "CUTWATCH_TOKEN in the environment; refusing to start"
        )
    if settings.source == "opcua" and (not settings.opcua_url or settings.opcua_nodes is None):
        raise CutwatchError(
            "source opcua needs a server and a node map: --opcua opc.tcp://host:port and "
            "--nodes MAP.json (CUTWATCH_OPCUA_URL, CUTWATCH_OPCUA_NODES)"
        )
    if (settings.source == "mqtt" or settings.mqtt_publish_hz > 0) and not settings.mqtt_broker:
        what = "source mqtt" if settings.source == "mqtt" else "mqtt_publish_hz > 0"
        raise CutwatchError(
            f"{what} needs a broker: set CUTWATCH_MQTT_BROKER (or --broker) to mqtt://host[:port]"
        )
