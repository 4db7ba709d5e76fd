"""The viser 3D view of the stage: its own server on its own, pinned port, on loopback.

viser has no authentication of its own, so its server listens on 127.0.0.1 only and the
browser reaches it through the app (``/viser/``, :mod:`server.service.routes.viser_proxy`),
behind the app's session. viser's share feature (a viewer's request makes the server
open a public tunnel through share.viser.studio) is switched off here: the share button
hidden and the server's handlers of share requests removed (:func:`disable_share`).

Scene: the machine bed; the ball screw turning with the motor angle; the table and the
workpiece moving with the load position (the workpiece shrinking as material is
removed); the spindle and the tool turning at the spindle speed, the tool off the
spindle axis by its eccentricity drawn ``ECC_SCALE`` times larger; the tool's colour
going from silver (sharp) to red at the flank-wear limit; the cutting force as arrows
(true: black, adaptive observer: blue).

:meth:`StageScene.update` is called from the loop thread with the latest values; it
coalesces to at most ``max_hz`` updates per second (latest values win).
"""

from __future__ import annotations

import contextlib
import math
import socket
import time
from typing import Any

import numpy as np

from server.errors import CutwatchError

FORCE_SCALE = 0.02  # arrow length per N m of cutting torque [m]
BLANK = (0.16, 0.12, 0.06)  # workpiece (x, y, z) when fresh [m]


ECC_SCALE = 200.0  # the tool's eccentricity drawn this many times larger


def _quat_axis(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    s = math.sin(0.5 * angle)
    return np.array([math.cos(0.5 * angle), axis[0] * s, axis[1] * s, axis[2] * s])


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of two quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


#: where viser listens: loopback only, whatever address the app binds
VISER_HOST = "127.0.0.1"


def disable_share(server: Any) -> None:
    """Switch off viser's share URL: no button, no handler, no method that opens a tunnel.

    viser (1.x) offers ``configure_theme(show_share_button=False)`` to hide the button;
    the server still answers a client's ``ShareUrlRequest`` message by calling
    ``request_share_url()``, which connects out to share.viser.studio. Both message
    handlers are removed, and ``request_share_url`` is replaced by a refusal.
    """
    from viser import _messages

    server.gui.configure_theme(show_share_button=False)
    infra = getattr(server, "_websock_server", None)
    for cls in (_messages.ShareUrlRequest, _messages.ShareUrlDisconnect):
        with contextlib.suppress(AssertionError, KeyError, AttributeError):
            infra.unregister_handler(cls)  # type: ignore[union-attr]

    def refused(verbose: bool = True) -> None:
        return None

    server.request_share_url = refused


def check_port_free(host: str, port: int) -> None:
    """Raise :class:`CutwatchError` if ``port`` cannot be bound (viser would drift)."""
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError as exc:
            raise CutwatchError(
                f"viser port {port} on {host} is not free ({exc.strerror}); "
                "choose another with --viser-port"
            ) from None


class StageScene:
    """A running viser server showing the stage.

    Parameters
    ----------
    host, port
        Where viser listens (loopback: :data:`VISER_HOST`). The port is pinned: if it
        is taken, :class:`CutwatchError` (viser itself would move to the next free port).
    max_hz
        Most scene updates per second.
    """

    def __init__(self, host: str, port: int, max_hz: float = 30.0) -> None:
        import viser

        check_port_free(host, port)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if self.server.get_port() != port:
            got = self.server.get_port()
            self.server.stop()
            raise CutwatchError(f"viser port {port} was taken (viser moved to {got})")
        disable_share(self.server)
        self.port = port
        self.period = 1.0 / max_hz
        self._last = -math.inf
        self._spindle_angle = 0.0
        self._t_prev: float | None = None
        self.updates = 0
        # the view opens on the stage (the 0.9 m bed fills about half of it), z up
        cam = self.server.initial_camera
        cam.up = (0.0, 0.0, 1.0)
        cam.look_at = (0.0, 0.0, 0.05)
        cam.position = (0.45, -0.6, 0.4)
        sc = self.server.scene
        sc.add_box(
            "/bed", color=(90, 96, 110), dimensions=(0.9, 0.36, 0.06), position=(0.0, 0.0, -0.03)
        )
        along_x = _quat_axis((0.0, 1.0, 0.0), math.pi / 2)  # cylinders stand on z
        self._along_x = along_x
        self.screw = sc.add_cylinder(
            "/screw",
            radius=0.012,
            height=0.8,
            color=(170, 170, 180),
            wxyz=along_x,
            position=(0.0, 0.0, 0.03),
        )
        # a stripe on the screw makes its turning visible
        self.stripe = sc.add_box(
            "/screw/stripe",
            color=(220, 60, 40),
            dimensions=(0.006, 0.004, 0.8),
            position=(0.0, 0.012, 0.0),
        )
        sc.add_box(
            "/motor", color=(40, 40, 45), dimensions=(0.08, 0.08, 0.08), position=(-0.44, 0.0, 0.03)
        )
        self.table = sc.add_box(
            "/table",
            color=(120, 140, 170),
            dimensions=(0.24, 0.3, 0.03),
            position=(0.0, 0.0, 0.075),
        )
        self.work = sc.add_box(
            "/table/work",
            color=(200, 170, 90),
            dimensions=BLANK,
            position=(0.0, 0.0, 0.015 + BLANK[2] / 2),
        )
        self.spindle = sc.add_cylinder(
            "/spindle", radius=0.035, height=0.14, color=(60, 60, 70), position=(0.0, 0.0, 0.29)
        )
        self.tool = sc.add_cylinder(
            "/spindle/tool",
            radius=0.006,
            height=0.1,
            color=(230, 230, 235),
            position=(0.0, 0.0, -0.12),
        )
        self.flute = sc.add_box(
            "/spindle/tool/flute", color=(30, 30, 30), dimensions=(0.013, 0.002, 0.1)
        )
        self.arrows = sc.add_arrows(
            "/force",
            points=np.zeros((2, 2, 3)),
            colors=np.array([[20, 20, 20], [0, 114, 178]], np.uint8),
            shaft_radius=0.004,
            head_radius=0.01,
            head_length=0.02,
        )
        self.label = sc.add_label("/label", "cutwatch stage", position=(-0.44, 0.0, 0.12))

    def update(
        self, latest: dict[str, float], removed: float, t: float, *, force: bool = False
    ) -> bool:
        """Move the scene to the latest values; skipped if called again within 1/max_hz,
        and while no viser client is connected (unless ``force``).

        Returns True if the scene was updated.
        """
        now = time.monotonic()
        if now - self._last < self.period or not latest:
            return False
        if not self.server.get_clients() and not force:
            return False  # nobody is looking: spend nothing (the scene catches up on connect)
        self._last = now
        q_m = latest.get("q_m", 0.0)
        x_l = latest.get("x_l", 0.0)
        rpm = latest.get("spindle_rpm", 0.0)
        dt = 0.0 if self._t_prev is None else max(0.0, t - self._t_prev)
        self._t_prev = t
        self._spindle_angle = (self._spindle_angle + 2 * math.pi * rpm / 60.0 * dt) % (2 * math.pi)
        frac = min(max(1.0 - removed, 0.05), 1.0)
        f_true = latest.get("f_true", 0.0)
        f_est = latest.get("f_adaptive", 0.0)
        # wear shown on the tool: silver when sharp, red at the flank-wear limit
        wear = latest.get("vb_true", 0.0) / max(latest.get("vb_limit", 0.3), 1e-9)
        wear = min(max(wear if math.isfinite(wear) else 0.0, 0.0), 1.0)
        tool_color = (230, int(230 * (1 - wear)), int(235 * (1 - wear)))
        with self.server.atomic():
            self.screw.wxyz = _qmul(_quat_axis((1.0, 0.0, 0.0), q_m % (2 * math.pi)), self._along_x)
            self.table.position = (x_l, 0.0, 0.075)
            self.work.scale = (1.0, 1.0, frac)
            self.work.position = (0.0, 0.0, 0.015 + frac * BLANK[2] / 2)
            self.spindle.wxyz = _quat_axis((0.0, 0.0, 1.0), self._spindle_angle)
            self.tool.color = tool_color
            # the tool's eccentricity, exaggerated ECC_SCALE times (20 um -> 4 mm), in the
            # turning spindle's frame
            e = latest.get("ecc_true_um", 0.0) * 1e-6 * ECC_SCALE
            e = e if math.isfinite(e) else 0.0
            th = math.radians(latest.get("ecc_true_deg", 0.0) or 0.0)
            th = th if math.isfinite(th) else 0.0
            self.tool.position = (e * math.cos(th), e * math.sin(th), -0.12)
            z, dy = 0.17, 0.02
            pts = np.array(
                [
                    [[0.0, 0.0, z], [FORCE_SCALE * f_true, 0.0, z]],
                    [[0.0, dy, z], [FORCE_SCALE * f_est, dy, z]],
                ],
                dtype=np.float32,
            )
            self.arrows.points = pts
        self.updates += 1
        return True

    def stop(self) -> None:
        """Stop the viser server."""
        self.server.stop()
