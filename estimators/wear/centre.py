r"""Flank wear per tool from the spindle's cutting power (issue 31 item 2, issue 35 item 7).

A CNC gives neither the width nor the depth of a cut, so the wear is read as the cutting
power of a block execution relative to the *taught fresh-tool value* of the same (tool,
program, block): the mean cutting power of the block's first ``teach`` executions by a
fresh instance of the tool (the process monitor's teach-in, on the power).

**The reading.** One per execution of a cut block at 100 % feed override (an override
changes the chip and with it the power by about as much as the wear does: those
executions are not read), ``z = P / P_ref - 1``.

**The map** (seed 004's output relation, eq. 22-24, the static part removed by the taught
reference; the wear part linear, its ``a1``): ``z = a_b (VB - VB_t)``, ``VB_t`` the flank
wear while the reference was taught (the break-in is fast: a prior, ``vb_taught``). The
gain ``a_b`` is one per (tool, program, block). Before any labelled life of the tool
it is the **prior**: a relative rise of the cutting power at the wear limit of
``rise_at_limit`` (median) with a log-normal spread ``rise_log_sd`` - the
"uncalibrated" state, whose interval carries that spread. Each labelled life (the VB
measured at a tool change, :meth:`CentreWear.label`) gives ``a_b = z_end / (VB_m - VB_t)``
from the block's last readings of that life; the gain is then their geometric mean with
a spread of ``between_log_sd`` (the empirical spread once three lives are in) - the
"calibrated" state.

**The state** (seed 004's structure): per tool ``(VB, r)``, ``VB(k+1) = VB(k) + r dt``,
``r >= 0`` (projected: the modelled wear never shrinks; the estimate may be revised),
the rate a random walk, advanced by the **seconds of cutting** of each execution (the
rate is indexed by cutting time, VB per second in the cut). A Kalman filter over the
readings at the gain's median, a 5-S.D. innovation gate; the 95 % interval widens the
filter's by the gain's spread (``VB - VB_t`` scales as ``1 / a``) and by ``VB_t``'s
(it shifts every reading alike): both are common to all readings of a tool, so the
filter cannot average them away.

**A new instance** (the CNC's trace does not say when a worn tool was replaced): two
consecutive readings of a tool that fall below the filter's prediction by more than the
gate and lie in the fresh tool's band (``-0.5 <= z <= fresh_band``: a fresh instance
reads ``a (0 - VB_t)``, a little below 0; a missing tool about -1) end its life; the
state restarts at VB 0. A label uses the life's last two *accepted* readings of each
block (a gated reading, such as the new instance's first, is not the worn tool's). A
tool replaced before its reading rose above that band is not seen as changed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from estimators.errors import ParameterError

__all__ = ["BlockKey", "CentreWear", "CentreWearParams", "CentreWearState", "Life", "Reading"]

Z95 = 1.959963984540054
#: a block: (tool, program, line)
BlockKey = tuple[int, str, int]


@dataclass(frozen=True)
class CentreWearParams:
    """The estimator's constants (SI units: VB in m, time in s).

    ``vb_limit``: the stated flank-wear limit (ISO 8688-2, 0.3 mm); ``teach``: executions
    averaged into a block's fresh reference; ``min_cut_w``: a block whose taught mean
    cutting power is below this is not a cut (air, a ramp); ``vb_taught``, ``vb_taught_sd``:
    the prior of VB while the reference is taught; ``rise_at_limit``, ``rise_log_sd``: the
    prior gain, the relative rise of the cutting power at ``vb_limit`` (median, log S.D.:
    0.47 puts 95 % between 16 % and 100 %, the range reported for carbide mills);
    ``between_log_sd``: the gain's spread between lives once labelled; ``label_sd``: the
    S.D. of a measured VB; ``reading_sd``: S.D. of one reading (depth of cut from blank to
    blank, the drive's noise); ``rate0``, ``rate0_sd``: the prior wear rate [m/s of
    cutting]; ``q``: the rate's random-walk variance [(m/s)^2 per s]; ``gate``: the
    innovation gate [S.D.]; ``fresh_band``: a reading below this (and
    above -0.5: not a missing tool, whose power is gone) is a fresh tool's.
    """

    vb_limit: float = 0.3e-3
    teach: int = 3
    min_cut_w: float = 50.0
    vb_taught: float = 0.02e-3
    vb_taught_sd: float = 0.015e-3
    rise_at_limit: float = 0.4
    rise_log_sd: float = 0.47
    between_log_sd: float = 0.15
    label_sd: float = 0.01e-3
    reading_sd: float = 0.03
    rate0: float = 0.3e-3 / 300.0
    rate0_sd: float = 0.3e-3 / 300.0
    q: float = (0.3e-3 / 300.0) ** 2 / 300.0
    gate: float = 5.0
    fresh_band: float = 0.08

    def __post_init__(self) -> None:
        for n in ("vb_limit", "min_cut_w", "rise_at_limit", "rise_log_sd", "reading_sd",
                  "rate0_sd", "q", "gate", "fresh_band", "label_sd", "vb_taught_sd"):  # fmt: skip
            v = getattr(self, n)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ParameterError(n, "a finite value > 0", v)
        if not (isinstance(self.teach, int) and self.teach >= 1):
            raise ParameterError("teach", "an integer >= 1", self.teach)
        for n in ("vb_taught", "rate0", "between_log_sd"):
            v = getattr(self, n)
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(n, "a finite value >= 0", v)


@dataclass
class BlockRef:
    """A block's taught fresh-tool reference, its labelled gains, its last readings."""

    sum_w: float = 0.0
    n: int = 0
    gains: list[float] = field(default_factory=list)
    last: list[float] = field(default_factory=list)  # this life's last readings


@dataclass
class ToolFilter:
    """One tool's wear state: (VB, rate) and its covariance, this life's bookkeeping."""

    x: np.ndarray
    P: np.ndarray
    instance: int = 1
    mount_t: float = 0.0
    cut_s: float = 0.0
    fresh_hits: int = 0
    last_t: float = 0.0


@dataclass
class Life:
    """A life ended (a new instance detected): what a label needs."""

    tool: int
    instance: int
    start_t: float
    end_t: float
    cut_s: float
    vb_est: float
    readings: dict[BlockKey, float]
    labelled: float = math.nan


@dataclass
class CentreWearState:
    """Every block's reference and every tool's filter; the lives ended so far."""

    blocks: dict[BlockKey, BlockRef] = field(default_factory=dict)
    tools: dict[int, ToolFilter] = field(default_factory=dict)
    lives: list[Life] = field(default_factory=list)


@dataclass(frozen=True)
class Reading:
    """What one execution gave: ``kind`` ``taught`` (into the reference), ``read``
    (filtered), ``gated`` (outside the gate), ``changed`` (a new instance), ``skipped``
    (not a cut, an override) or ``teaching``."""

    kind: str
    z: float = math.nan


class CentreWear:
    """The estimator (module docstring); its state is a :class:`CentreWearState`."""

    def __init__(self, params: CentreWearParams | None = None) -> None:
        self.params = params or CentreWearParams()

    def initial_state(self) -> CentreWearState:
        return CentreWearState()

    def _new_filter(self, t: float, instance: int = 1) -> ToolFilter:
        p = self.params
        return ToolFilter(
            np.array([0.0, p.rate0]), np.diag([1e-18, p.rate0_sd**2]), instance, t, 0.0, 0, t
        )

    def _tool(self, st: CentreWearState, tool: int, t: float) -> ToolFilter:
        if tool not in st.tools:
            st.tools[tool] = self._new_filter(t)
        return st.tools[tool]

    # ------------------------------------------------------------------ the map
    def gain(self, st: CentreWearState, key: BlockKey) -> tuple[float, float, bool]:
        """``(a, log S.D., calibrated)`` of a block's map [1/m]."""
        p = self.params
        g = st.blocks[key].gains if key in st.blocks else []
        if not g:
            return p.rise_at_limit / (p.vb_limit - p.vb_taught), p.rise_log_sd, False
        lg = np.log(g)
        sd = float(np.std(lg, ddof=1)) if len(g) >= 3 else p.between_log_sd
        return float(np.exp(np.mean(lg))), max(sd, 0.05), True

    def calibrated(self, st: CentreWearState, tool: int) -> bool:
        """Every cut block of ``tool`` has a labelled gain."""
        keys = [k for k, b in st.blocks.items() if k[0] == tool and self._is_cut(b)]
        return bool(keys) and all(st.blocks[k].gains for k in keys)

    def _is_cut(self, b: BlockRef) -> bool:
        return b.n >= self.params.teach and b.sum_w / b.n >= self.params.min_cut_w

    # ------------------------------------------------------------------ a reading
    def observe(
        self,
        st: CentreWearState,
        key: BlockKey,
        mean_w: float,
        seconds: float,
        t: float,
        override: float = 1.0,
    ) -> tuple[CentreWearState, Reading]:
        """One execution of block ``key`` that ended at ``t``: its mean cutting power
        ``mean_w`` [W] over ``seconds`` of known (steady) cutting power at ``override``."""
        p = self.params
        tool = key[0]
        tf = self._tool(st, tool, t)
        if not (math.isfinite(mean_w) and seconds > 0):
            return st, Reading("skipped")
        b = st.blocks.setdefault(key, BlockRef())
        if abs(override - 1.0) > 0.02:
            return st, Reading("skipped")
        if b.n < p.teach:
            # taught by the first instance (fresh): its first executions
            b.sum_w += mean_w
            b.n += 1
            self._predict(tf, seconds, t)
            return st, Reading("taught" if b.n == p.teach else "teaching")
        if not self._is_cut(b):
            return st, Reading("skipped")
        z = mean_w / (b.sum_w / b.n) - 1.0
        self._predict(tf, seconds, t)
        a, _, _ = self.gain(st, key)
        h = np.array([a, 0.0])
        pred = a * (tf.x[0] - p.vb_taught)
        r = p.reading_sd**2  # VB_t's uncertainty is common to all readings: in the interval
        s = float(h @ tf.P @ h) + r
        nu = z - pred
        if nu < -p.gate * math.sqrt(s) and -0.5 <= z <= p.fresh_band:
            tf.fresh_hits += 1
            if tf.fresh_hits >= 2:
                self._change(st, tool, t)
                nt = st.tools[tool]
                nt.cut_s += seconds
                return st, Reading("changed", z)
            return st, Reading("gated", z)
        tf.fresh_hits = 0
        if abs(nu) > p.gate * math.sqrt(s):
            return st, Reading("gated", z)
        b.last = [*b.last[-1:], z]  # the life's last accepted readings (for a label)
        k = tf.P @ h / s
        tf.x = tf.x + k * nu
        tf.P = tf.P - np.outer(k, h @ tf.P)
        tf.x[1] = max(tf.x[1], 0.0)
        return st, Reading("read", z)

    def _predict(self, tf: ToolFilter, dt: float, t: float) -> None:
        q = self.params.q
        f = np.array([[1.0, dt], [0.0, 1.0]])
        qm = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        tf.x = f @ tf.x
        tf.P = f @ tf.P @ f.T + qm
        tf.cut_s += dt
        tf.last_t = t

    def _change(self, st: CentreWearState, tool: int, t: float) -> None:
        old = st.tools[tool]
        reads = {k: float(np.mean(b.last)) for k, b in st.blocks.items() if k[0] == tool and b.last}
        st.lives.append(Life(tool, old.instance, old.mount_t, t, old.cut_s, float(old.x[0]), reads))
        for k, b in st.blocks.items():
            if k[0] == tool:
                b.last = []
        st.tools[tool] = self._new_filter(t, old.instance + 1)

    # ------------------------------------------------------------------ labels
    def label(self, st: CentreWearState, tool: int, vb: float) -> Life:
        """The VB measured [m] on ``tool`` at its latest tool change not yet labelled:
        each of its blocks' gains gets that life's ``a_b``.

        Raises
        ------
        ParameterError
            ``vb`` not finite or not in (0, 3 x the limit]; no unlabelled ended life of
            ``tool``.
        """
        p = self.params
        if not (isinstance(vb, int | float) and math.isfinite(vb) and 0 < vb <= 3 * p.vb_limit):
            raise ParameterError("vb", f"a flank wear in (0, {3 * p.vb_limit:g}] m", vb)
        open_ = [lf for lf in st.lives if lf.tool == tool and not math.isfinite(lf.labelled)]
        if not open_:
            seen = sorted({lf.tool for lf in st.lives if not math.isfinite(lf.labelled)})
            raise ParameterError(
                "tool",
                "a tool with a tool change not yet labelled"
                + (f" ({', '.join(f'T{x}' for x in seen)})" if seen else " (none so far)"),
                tool,
            )
        life = open_[-1]
        life.labelled = float(vb)
        d = vb - p.vb_taught
        for k, z in life.readings.items():
            if d > 0 and z > 0:
                st.blocks[k].gains.append(z / d)
        return life

    # ------------------------------------------------------------------ the estimate
    def estimate(self, st: CentreWearState, tool: int) -> dict[str, float | bool]:
        """The tool's VB [m] now with its 95 % interval, its rate [m per cutting second],
        its remaining cutting seconds to the limit (inf at rate 0), and whether its map
        is calibrated."""
        p = self.params
        if tool not in st.tools:
            return {"vb": math.nan, "lo": math.nan, "hi": math.nan, "rate": math.nan,
                    "life_s": math.nan, "calibrated": False}  # fmt: skip
        tf = st.tools[tool]
        keys = [k for k, b in st.blocks.items() if k[0] == tool and self._is_cut(b)]
        sds = [self.gain(st, k)[1] for k in keys] or [p.rise_log_sd]
        e = math.exp(Z95 * max(sds))
        vb, sd = float(tf.x[0]), math.sqrt(max(float(tf.P[0, 0]), 0.0))
        lo_f, hi_f = vb - Z95 * sd, vb + Z95 * sd
        # the gain's spread and VB_t's are common to every reading of the tool (systematic,
        # not averaged away by the filter): VB - VB_t scales as 1 / a, VB_t shifts all
        t0, dt0 = p.vb_taught, Z95 * p.vb_taught_sd
        hi = (t0 + (hi_f - t0) * e if hi_f > t0 else hi_f) + dt0
        lo = (t0 + (lo_f - t0) / e if lo_f > t0 else lo_f) - dt0
        rate = float(tf.x[1])
        life = (p.vb_limit - vb) / rate if rate > 0 else math.inf
        return {"vb": vb, "lo": max(lo, 0.0), "hi": hi, "rate": rate,
                "life_s": max(life, 0.0), "calibrated": self.calibrated(st, tool)}  # fmt: skip
