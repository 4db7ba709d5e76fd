r"""The CNC's trace of the machining centre: its signals at 500 Hz, 1, 2.5 or 5 kHz.

A CNC hands out its drives' signals once per position-control cycle (2 ms: 500 Hz; 1 ms:
1 kHz), a drive's own trace faster (2.5 kHz, 5 kHz); the simulation runs at 10 kHz, so
each trace cycle holds ``factor = 10 kHz / rate`` simulated samples. What the trace does
with them (a choice per trace, ``mode``):

``sample`` (the default)
    Every signal is the value at the cycle's last simulated sample: one point sample per
    cycle, what a CNC reads when its cycle runs. Nothing filters above the trace's
    Nyquist frequency but what the drive itself has: the current loop (1.6 kHz), the
    speed actual value's filter (0.2 ms on the axes, 1 ms on the spindle), the CNC's
    power smoothing (10 ms). A tooth-passing line above the Nyquist frequency folds
    back at full strength.
``mean``
    The efforts and speeds (axis currents and speeds, spindle current and speed) are the
    cycle's average (a drive that integrates its current over the cycle): a boxcar of
    one cycle, gain :math:`|\mathrm{sinc}(f / f_{trace})|`, zero at every multiple of
    the trace rate, -3.9 dB at the Nyquist frequency, side lobes down to -13 dB: it
    attenuates what it folds back, it does not stop it. Positions, the commanded speed,
    the power and the identities stay point samples (an encoder is latched once per
    cycle; the power is already smoothed).

The truth (process forces, cutting torque, engagement, true speed) is the cycle's
average in both modes: the force an estimator at this rate can be scored against. The
time stamp of a trace sample is its cycle's last simulated sample.

:meth:`CncTrace.export` works block by block, carrying an unfinished cycle over to the
next record, so a trace of a run in pieces is the trace of the run in one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from machine.centre import kernel as kn
from machine.centre.sim import CentreRecord
from machine.errors import ParameterError
from machine.process import EventTruth

#: trace modes
MODES = ("sample", "mean")
#: trace rates offered [Hz] (divisors of the simulation's 10 kHz)
RATES = (500.0, 1000.0, 2500.0, 5000.0)
#: rows a ``mean`` trace averages over the cycle
MEAN_ROWS = tuple(
    kn.ROWS.index(n)
    for n in (*(f"{a}.{r}" for a in "XYZ" for r in ("qd_m", "i_m")), "S.speed", "S.current")
)
#: truth rows: always the cycle's average
TRUTH_ROWS = tuple(
    kn.ROWS.index(n)
    for n in (*(f"{a}.f_process" for a in "XYZ"), "S.torque_cut", "S.speed_true", "engaged")
)


@dataclass(frozen=True)
class TraceParams:
    """A trace: ``rate_hz`` (one of :data:`RATES`) and ``mode`` (one of :data:`MODES`)."""

    rate_hz: float = 500.0
    mode: str = "sample"

    def __post_init__(self) -> None:
        if self.rate_hz not in RATES:
            raise ParameterError("rate_hz", f"one of {list(RATES)} Hz", self.rate_hz)
        if self.mode not in MODES:
            raise ParameterError("mode", f"one of {list(MODES)}", self.mode)

    def factor(self, sample_time: float) -> int:
        """Simulated samples per trace cycle."""
        q = 1.0 / (self.rate_hz * sample_time)
        f = round(q)
        if f < 1 or abs(q - f) > 1e-9 * q:
            raise ParameterError(
                "rate_hz", f"a divisor of the simulation's {1.0 / sample_time:g} Hz", self.rate_hz
            )
        return f


@dataclass
class TraceState:
    """The unfinished cycle carried to the next record: its rows, identities, flank wear,
    first sample index, and the events whose first sample lies in it."""

    rows: F64
    ids: np.ndarray
    override: F64
    vb: F64
    k0: int
    events: list[EventTruth] = field(default_factory=list)


@dataclass
class TraceRecord:
    """Trace samples: ``t`` [s] (each cycle's last simulated sample), ``rows`` (the
    names of :data:`machine.centre.kernel.ROWS`), the identities ``tool``, ``line``,
    ``part``, ``override``, the truth ``vb`` [m], the ``program``, and the ``events``
    with ``trace_index`` the trace sample holding each one's first sample."""

    t: F64
    rows: F64
    tool: np.ndarray
    line: np.ndarray
    part: np.ndarray
    override: F64
    vb: F64
    program: str
    events: list[EventTruth]
    trace_index: list[int]

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    def signal(self, name: str) -> F64:
        try:
            return self.rows[kn.ROWS.index(name)]
        except ValueError:
            raise ParameterError("name", f"one of {list(kn.ROWS)}", name) from None


class CncTrace:
    """Export :class:`machine.centre.sim.CentreRecord` blocks as a CNC's trace.

    Examples
    --------
    >>> from machine.centre.sim import MachiningCentre
    >>> m = MachiningCentre()
    >>> trace = CncTrace(TraceParams(500.0, "sample"), m.sample_time)
    >>> st, ts = m.initial_state(0), trace.initial_state()
    >>> st, rec = m.step(st, 1000)
    >>> ts, tr = trace.export(ts, rec)
    >>> tr.n
    50
    """

    def __init__(self, params: TraceParams | None = None, sample_time: float = 1e-4) -> None:
        self.params = params if params is not None else TraceParams()
        self.sample_time = float(sample_time)
        self.factor = self.params.factor(self.sample_time)

    def initial_state(self) -> TraceState:
        return TraceState(
            rows=np.zeros((kn.N_ROWS, 0)), ids=np.zeros((3, 0), dtype=np.int64),
            override=np.zeros(0), vb=np.zeros(0), k0=0,
        )  # fmt: skip

    def export(self, state: TraceState, rec: CentreRecord) -> tuple[TraceState, TraceRecord]:
        """The trace samples of the cycles that end in ``rec`` (the rest carried over)."""
        if state.rows.shape[1] and state.k0 + state.rows.shape[1] != rec.k0:
            raise ParameterError(
                "rec.k0", f"the sample after the last exported ({state.k0 + state.rows.shape[1]})",
                rec.k0,
            )  # fmt: skip
        k0 = rec.k0 - state.rows.shape[1]
        rows = np.concatenate([state.rows, rec.rows], axis=1)
        ids = np.concatenate([state.ids, np.stack([rec.tool, rec.line, rec.part])], axis=1)
        ovr = np.concatenate([state.override, rec.override])
        vb = np.concatenate([state.vb, rec.vb])
        events = [*state.events, *rec.events]
        f = self.factor
        m = rows.shape[1] // f
        used = m * f
        out = self._rows(rows[:, :used], m)
        last = np.arange(m) * f + f - 1
        done = [e for e in events if e.sample < k0 + used]
        tr = TraceRecord(
            t=(k0 + last) * self.sample_time, rows=out, tool=ids[0, last], line=ids[1, last],
            part=ids[2, last], override=ovr[last], vb=vb[last], program=rec.program,
            events=done, trace_index=[(e.sample - k0) // f for e in done],
        )  # fmt: skip
        rest = TraceState(
            rows=rows[:, used:].copy(), ids=ids[:, used:].copy(), override=ovr[used:].copy(),
            vb=vb[used:].copy(), k0=k0 + used,
            events=[e for e in events if e.sample >= k0 + used],
        )  # fmt: skip
        return rest, tr

    def _rows(self, rows: F64, m: int) -> F64:
        f = self.factor
        out = np.ascontiguousarray(rows[:, f - 1 :: f])
        if m == 0:
            return out
        avg = list(TRUTH_ROWS + (MEAN_ROWS if self.params.mode == "mean" else ()))
        out[avg] = rows[avg].reshape(len(avg), m, f).mean(axis=2)
        return out


__all__ = ["MEAN_ROWS", "MODES", "RATES", "TRUTH_ROWS", "CncTrace", "TraceParams",
           "TraceRecord", "TraceState"]  # fmt: skip
