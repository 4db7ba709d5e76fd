"""A CNC's OPC UA server as a measurement source (issue 33).

:class:`OpcuaSource` satisfies :class:`server.pipeline.sources.MeasurementSource` over an
:class:`server.pipeline.opcua_link.OpcuaLink` (the client thread: security, the
subscription, reconnects) and a :class:`server.pipeline.opcua_grid.TimeGrid` (the
samples on one time grid, sample-and-hold counted). Each :meth:`OpcuaSource.step` moves
the samples that arrived to the grid, hands out the cells every sample of has arrived
(the watermark: the newest server time seen, or the server's clock estimated from the
arrivals during quiet spells, less a publishing and a sampling interval) and marks the
first block after a reconnect as a discontinuity.

The node map (:mod:`server.records.opcua_map`) is the machine description: the block's
``columns`` carry every signal by its node id, in the description's units (each node's
``EngineeringUnits`` converted, or the map's unit when it states one: said in
:meth:`OpcuaSource.status`); the block's :class:`machine.stage.Measurements` are those of
the first axis (the motor effort as a torque when ``K_t`` is known).

The sample time is the sampling interval the server revised, when it has answered (said
when it differs from the map's): :attr:`OpcuaSource.needs_rebuild` then asks the live loop
for a new pipeline at that rate (:meth:`OpcuaSource.renewed`: the same link and counts).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from common.machine_description import MAX_SAMPLE_TIME, MIN_SAMPLE_TIME, MachineDescription
from machine.stage import SEED000_FORCE, Measurements, StageConfig
from machine.stage_params import preset
from server.errors import CutwatchError
from server.pipeline.opcua_grid import TimeGrid
from server.pipeline.opcua_link import CONNECTED, OpcuaLink, OpcuaSecurity
from server.pipeline.sources import (
    NOMINAL,
    RESUMED,
    LiveSource,
    SourceBlock,
    TruthSummary,
    empty_measurements,
    nominal_config,
)
from server.records.opcua_map import NodeMap, eu_factor

__all__ = ["QUIET_S", "OpcuaOptions", "OpcuaSource"]

#: how long a feed must say nothing at all before the grid holds its values [s]
QUIET_S = 2.0


@dataclass(frozen=True)
class OpcuaOptions:
    """A source's connection: the server's ``url``, the publishing interval [s] (None: the
    sample time, at least 0.1 s: a CNC's fastest), the security and the longest wait
    between connection attempts [s]."""

    url: str
    publishing_s: float | None = None
    security: OpcuaSecurity = field(default_factory=OpcuaSecurity)
    backoff_max_s: float = 5.0


class OpcuaSource(LiveSource):
    """A CNC's OPC UA server as a source (see the module docstring)."""

    name = "opcua"
    has_truth = False
    knobs_apply = False
    paced = False
    finished = False

    def __init__(
        self, node_map: NodeMap, options: OpcuaOptions, link: OpcuaLink | None = None
    ) -> None:
        self.node_map = node_map
        self.options = options
        desc = node_map.description
        self.sources = [s.source for s in desc.signals() if s.owner != "identities"]
        self.identity_sources = dict(desc.identities)
        if link is None:
            ts = desc.sample_time
            pub = options.publishing_s if options.publishing_s is not None else max(ts, 0.1)
            link = OpcuaLink(
                options.url, [*self.sources, *self.identity_sources.values()], ts, pub,
                options.security, options.backoff_max_s,
            )  # fmt: skip
        self.link = link
        self._revised = link.info.revised_sampling_s
        self.description = self._described(desc)
        ts = self.description.sample_time
        self._cfg = StageConfig(params=preset("seed000"), force=SEED000_FORCE, sample_time=ts)
        ax = self.description.axes[0]
        if not self.stage_refusal:  # the stage's observers are built from the nominal
            nom = {**ax.nominal, **({"K_t": ax.K_t} if ax.K_t else {})}
            self._cfg = nominal_config(nom, ts, ax.encoder_resolution)
        numeric = [*self.sources, *self.identity_sources.values()]
        self.grid = TimeGrid(numeric, ts)
        self.text: dict[str, str] = {}  # a text node's (the program's) latest value
        self.factors: dict[str, float] = {}
        self.unit_notes: list[str] = []
        self._units_done = False
        self._pending: list[tuple[F64, dict[str, F64], str | None]] = []
        self._origin: float | None = None
        self._t = 0.0
        self._taken = 0
        self._offset = -math.inf  # server clock - our clock, estimated from arrivals
        self._newest = -math.inf
        self._last_arrival: float | None = None  # wall time the last sample arrived
        self._connects = 0
        self._resumed = False
        self.latency: list[float] = []  # arrival - server time of the newest sample [s]
        self.last_wall: float | None = None

    # -- the description at the revised rate ---------------------------------------------
    def _described(self, desc: MachineDescription) -> MachineDescription:
        r = self._revised
        if not math.isfinite(r) or abs(r - desc.sample_time) <= 1e-9 * desc.sample_time:
            return desc
        if not MIN_SAMPLE_TIME <= r <= MAX_SAMPLE_TIME * (1 + 1e-9):
            raise CutwatchError(
                f"the server revised the sampling interval to {r:g} s: outside the "
                f"{MIN_SAMPLE_TIME:g}-{MAX_SAMPLE_TIME:g} s a machine description allows"
            )
        return desc.with_sample_time(r)

    @property
    def kind(self) -> str:
        return self.description.axes[0].kind

    @property
    def stage_refusal(self) -> str:
        """Why seed 000's two-inertia observers cannot be built on this machine (empty:
        they can): they need a rotary two-inertia first axis with its nominal
        parameters (J_M, J_L, K, K_t, B_M, B_L, F_CM, F_CL)."""
        ax = self.description.axes[0]
        missing = [k for k in NOMINAL if k not in ax.nominal and not (k == "K_t" and ax.K_t)]
        if ax.kind == "two_inertia" and ax.position_unit == "rad" and not missing:
            return ""
        return (
            f"seed 000's observers need a rotary two-inertia first axis with its nominal "
            f"{', '.join(NOMINAL)}; the opcua source's axis {ax.name} is {ax.kind} in "
            f"{ax.position_unit}" + (f" without {', '.join(missing)}" if missing else "")
        )

    @property
    def needs_rebuild(self) -> bool:
        """True when the server revised the sampling interval after this source was built."""
        r = self.link.info.revised_sampling_s
        return math.isfinite(r) and not math.isclose(r, self.description.sample_time, rel_tol=1e-9)

    def renewed(self) -> OpcuaSource:
        """A source on the same link at the revised sampling interval."""
        return OpcuaSource(self.node_map, self.options, self.link)

    def start(self) -> None:
        self.link.start()

    def stop(self) -> None:
        self.link.stop()

    # -- units ---------------------------------------------------------------------------
    def _resolve_units(self) -> None:
        """Each node's factor from its EngineeringUnits, once the link has read them."""
        if self._units_done or not self.link.unit_ready.is_set():
            return
        self._units_done = True
        nm, units = self.node_map, self.link.info.units
        for sig in self.description.signals():
            if sig.owner == "identities":
                continue
            key = f"{sig.owner}.{sig.role}"
            eu = units.get(sig.source)
            unit = sig.unit
            if eu is None:
                continue
            target = unit
            try:
                f = eu_factor(*eu, target, spindle=sig.owner == "spindle")
            except CutwatchError as exc:
                if key in nm.stated_units:  # the map's unit is the values' unit
                    self.unit_notes.append(
                        f"{key}: the map's {unit} overrides the server's {eu[1] or eu[0]}"
                    )
                else:
                    self.unit_notes.append(f"{key}: {exc}; values taken as {unit}")
                continue
            if f is None:
                self.unit_notes.append(
                    f"{key}: the server's unit {eu[1]!r} is not known; values taken as {unit}"
                )
            elif f != 1.0:
                self.factors[sig.source] = f
                self.unit_notes.append(f"{key}: {eu[1]} converted to {target}")

    # -- MeasurementSource ---------------------------------------------------------------
    @property
    def t(self) -> float:
        return self._t

    def _drain(self) -> None:
        q = self.link.samples
        while q:
            name, ts, val, overflow, wall = q.popleft()
            if name == CONNECTED:
                self._connects += 1
                if self._connects > 1:
                    self.grid.restart("reconnected")
                continue
            if not math.isfinite(ts):
                continue
            self._offset = max(self._offset, ts - wall)
            self._newest = max(self._newest, ts)
            self._last_arrival = wall
            self.latency.append(wall - ts)
            if isinstance(val, str):  # a program's name, a block "N120": its number
                self.text[name] = val
                digits = re.findall(r"\d+", val)
                val = float(digits[-1]) if digits else math.nan
            try:
                v = float(val)
            except (TypeError, ValueError):
                v = math.nan
            self.grid.add(name, ts, v, overflow)
        if len(self.latency) > 5000:
            del self.latency[:-1000]

    def _watermark(self) -> float:
        """The server time every sample up to which has arrived: the newest timestamp
        less a publishing and a sampling interval. When nothing at all has arrived for
        :data:`QUIET_S` (the machine stands still: a subscription reports changes only),
        the grid goes on from the newest timestamp at the pace of the wall clock, holding
        the values; a server or a client stalled for less than that is waited for, so its
        late deliveries are not taken for silence."""
        margin = self.link.publishing_s + self.description.sample_time
        wm = self._newest - margin
        if self.link.info.state.startswith("connected") and self._last_arrival is not None:
            quiet = time.time() - self._last_arrival
            if quiet > QUIET_S:
                wm = max(wm, self._newest + quiet - QUIET_S - margin)
        return wm

    def step(self, n: int) -> SourceBlock:
        if self.needs_rebuild:
            return SourceBlock(empty_measurements())
        if self.link.info.connects == 0:  # the subscription's answer (its rate) first
            return SourceBlock(empty_measurements())
        self._resolve_units()
        self._drain()
        if math.isfinite(self._newest):
            gb = self.grid.advance(self._watermark())
            if gb.n:
                self._pending.append((gb.t, gb.columns, gb.discontinuity))
        if not self._pending:
            return SourceBlock(empty_measurements())
        t_abs, cols, disc = self._pending[0]
        k = min(max(int(n), 0), len(t_abs))
        if k == 0:
            return SourceBlock(empty_measurements())
        if k == len(t_abs):
            self._pending.pop(0)
        else:
            self._pending[0] = (t_abs[k:], {c: v[k:] for c, v in cols.items()}, None)
        return self._block(t_abs[:k], {c: v[:k] for c, v in cols.items()}, disc)

    def _block(self, t_abs: F64, cols: Mapping[str, F64], disc: str | None) -> SourceBlock:
        ts = self.description.sample_time
        if self._origin is None:
            self._origin = float(t_abs[0]) - self._t
        t = np.round((t_abs - self._origin) / ts) * ts
        self._t = float(t[-1] + ts)
        self._taken += len(t)
        columns = {c: v * self.factors.get(c, 1.0) for c, v in cols.items()}
        if self._resumed:
            disc, self._resumed = RESUMED, False
        self.last_wall = time.time()
        return SourceBlock(self._measurements(t, columns), None, disc, columns)

    def _measurements(self, t: F64, c: Mapping[str, F64]) -> Measurements:
        ax = self.description.axes[0]
        s = ax.signals
        nan = np.full(len(t), math.nan)
        k_t = ax.K_t
        if "tau_m" in s:
            tau = c[s["tau_m"]]
            i_m = tau / k_t if k_t else nan
        else:
            i_m = c[s["i_m"]]
            tau = i_m * k_t if k_t else i_m
        return Measurements(
            t=t,
            i_m=i_m,
            tau_m=tau,
            q_m=c[s["q_m"]],
            q_l=c[s["q_l"]] if "q_l" in s else nan,
            f_ext=c[s["f_ext"]] if "f_ext" in s else nan,
        )

    def _forget_origin(self) -> None:
        self._origin = None

    def truth_summary(self) -> TruthSummary:
        return {"server": self.options.url}

    def status(self) -> dict[str, object]:
        info = self.link.info
        mapped = self.node_map.description.sample_time
        rev = info.revised_sampling_s
        said = ""
        if math.isfinite(rev) and not math.isclose(rev, mapped, rel_tol=1e-9):
            said = f"the server revised the sampling interval from {mapped:g} s to {rev:g} s"
        lat = sorted(self.latency[-1000:])
        return {
            "state": info.state,
            "server": self.options.url,
            "connected": info.state.startswith("connected"),
            "policy": info.policy,
            "server_thumbprint": info.server_thumbprint,
            "connects": info.connects,
            "attempts": info.attempts,
            "last_error": info.last_error,
            "sample_time": self.description.sample_time,
            "requested_sampling_s": mapped,
            "revised_sampling_s": rev,
            "sampling_note": said,
            "queue_size": info.queue_size,
            "nodes": len(self.grid.nodes),
            "taken": self._taken,
            "buffered": sum(len(p[0]) for p in self._pending),
            "units": list(self.unit_notes),
            "identities": dict(self.text),
            "latency_ms_median": 1e3 * lat[len(lat) // 2] if lat else math.nan,
            **self.grid.counts.as_dict(),
        }
