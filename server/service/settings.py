"""Settings of the live service, read from the environment (prefix ``CUTWATCH_``).

Examples: ``CUTWATCH_PORT=8001``, ``CUTWATCH_SPEED=0`` (start paused),
``CUTWATCH_HOST=0.0.0.0 CUTWATCH_TOKEN=...`` (any address other than loopback needs a
token; see :func:`check_security`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from server.errors import CutwatchError

LOOPBACK = frozenset({"127.0.0.1", "localhost", "::1"})
MAX_SPEED = 1000.0


class Settings(BaseSettings):
    """Configuration of ``cutwatch serve`` (every field also ``CUTWATCH_<FIELD>``)."""

    model_config = SettingsConfigDict(env_prefix="CUTWATCH_", extra="ignore", validate_default=True)

    host: str = Field(default="127.0.0.1", description="address to bind (loopback by default)")
    port: int = Field(default=8000, ge=1, le=65535, description="HTTP / WebSocket port")
    viser_port: int = Field(default=8080, ge=1, le=65535, description="port of the viser 3D view")
    scenario: str = Field(default="default", description="scenario at start (see /api/scenarios)")
    speed: float = Field(
        default=1.0,
        ge=0.0,
        le=MAX_SPEED,
        description="simulated seconds per wall second (0 = paused)",
    )
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
    max_lag_s: float = Field(
        default=2.0, gt=0.0, le=60.0, description="lag after which the loop re-anchors its clock"
    )
    token: SecretStr | None = Field(default=None, description="bearer token for mutating endpoints")
    seed: int = Field(default=0, ge=0, description="seed of the simulation's random generators")
    viser: bool = Field(default=True, description="start the viser 3D view on viser_port")
    source: Literal["simulator", "mqtt"] = Field(
        default="simulator",
        description=(
            "where the measurements come from: the simulated machine, or a real machine's "
            "drive blocks on the broker (mqtt_broker, mqtt_machine)"
        ),
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
        default=None, description="CA certificate file: connect to the broker with TLS"
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
    checkpoint_s: float = Field(
        default=10.0,
        ge=0.0,
        le=86_400.0,
        description=(
            "save the pipeline's state to data_dir/state/pipeline.npz this often [wall s] "
            "and at shutdown, and resume from it at start (docs/checkpoints.md); 0: never"
        ),
    )
    record_max_mb: float = Field(
        default=200.0, gt=0.0, le=100_000.0, description="largest recording [MB] (then it stops)"
    )
    record_max_minutes: float = Field(
        default=60.0, gt=0.0, le=10_080.0, description="longest recording [min] (then it stops)"
    )
    upload_max_mb: float = Field(
        default=100.0, gt=0.0, le=100_000.0, description="largest uploaded file [MB] (413 above)"
    )

    @property
    def reports_area(self) -> Path:
        """Where residual reports live: ``reports_dir`` if set, else ``data_dir/reports``."""
        return self.reports_dir if self.reports_dir is not None else self.data_dir / "reports"

    @property
    def upload_max_bytes(self) -> int:
        return int(self.upload_max_mb * 1e6)


def is_loopback(host: str) -> bool:
    """True if ``host`` is a loopback address."""
    return host in LOOPBACK or host.startswith("127.")


def check_security(settings: Settings) -> None:
    """Refuse to serve on a non-loopback address without a bearer token.

    Raises
    ------
    CutwatchError
        If ``settings.host`` is not loopback and no (non-empty) token is set.
    """
    token = settings.token.get_secret_value() if settings.token is not None else ""
    if not is_loopback(settings.host) and not token:
        raise CutwatchError(
            f"binding to {settings.host!r} (not loopback) requires a bearer token: set "
            "CUTWATCH_TOKEN in the environment; refusing to start"
        )
    if (settings.source == "mqtt" or settings.mqtt_publish_hz > 0) and not settings.mqtt_broker:
        what = "source mqtt" if settings.source == "mqtt" else "mqtt_publish_hz > 0"
        raise CutwatchError(
            f"{what} needs a broker: set CUTWATCH_MQTT_BROKER (or --broker) to mqtt://host[:port]"
        )
