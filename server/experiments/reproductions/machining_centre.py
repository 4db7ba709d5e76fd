"""The machining centre of issue 31: its stated numbers, and what its CNC trace sees.

Not a paper's experiment: the machine (``machine.centre``) is ours, so the rows have no
paper column; they are the numbers the docs state, computed from the model, and what a
CNC's trace of it shows, measured on simulated parts.

1. The machine: the X axis' first axial mode and anti-resonance, its stiffness; per axis
   the closed-loop bandwidths of the speed and position loops from the discrete loop
   (``machine.centre.loops``); the spindle's; the Z motor's holding current measured in
   the simulation against m g / K_f; the idle power at each programmed speed measured
   in the air against the friction model; the part time.
2. The trace's spectrum, over seeds (each seed a part with its own noise, depth of cut
   and override): per tool of the default program, the tooth-passing line of the
   Y axis' current (the feed force of the side cut is mostly along Y) in the simulated
   signal (10 kHz) and in 500 Hz traces, point-sampled and cycle-averaged. A line above
   the Nyquist frequency folds to ``|f - k 500|``; its amplitude there over its
   amplitude at 10 kHz is the row (theory: 1 for a point sample, ``|sinc(f / 500)|``
   for a cycle average); checked on the mean over the seeds. Also the X axis' torsion
   (encoder minus scale) ringing at its mode after the rapids, at 10 kHz and in the
   500 Hz trace.

``--plot DIR`` writes ``machining_centre_spectrum.png``: the spectra of the simulated
signal beside the 500 Hz traces (docs/machining-centre.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from machine.centre.loops import bandwidth_hz, closed_loop, stable
from machine.centre.params import CentreParams
from machine.centre.sim import CentreRecord, MachiningCentre
from machine.centre.trace import CncTrace, TraceParams, TraceRecord
from server.experiments.reproduction import Check, Reproduction, Row, Section

NAME = "machining-centre"
SOURCE = "issue 31: the machining centre's stated numbers and its 500 Hz trace (no paper)"
#: samples of one default part and a little more (10 kHz)
PART_SAMPLES = 330_000
#: the cut of each tool of the default program: (line, tool, rpm, flutes)
CUTS = ((60, 1, 3000.0, 4), (140, 2, 8000.0, 3), (250, 3, 10000.0, 2))
TRACE_HZ = 500.0
SEEDS_QUICK, SEEDS_FULL = 6, 20


@dataclass
class PartRun:
    """One simulated part and its 500 Hz traces."""

    machine: MachiningCentre
    full: CentreRecord
    traces: dict[str, TraceRecord]


def simulate_part(seed: int) -> PartRun:
    """One default part (seed: the noise, the depth of cut, the override)."""
    m = MachiningCentre()
    st = m.initial_state(seed=seed)
    recs = []
    for _ in range(PART_SAMPLES // 10_000):
        st, rec = m.step(st, 10_000)
        recs.append(rec)
    full = _join(recs)
    traces = {}
    for mode in ("sample", "mean"):
        trace = CncTrace(TraceParams(TRACE_HZ, mode), m.sample_time)
        _, traces[mode] = trace.export(trace.initial_state(), full)
    return PartRun(m, full, traces)


def _join(recs: list[CentreRecord]) -> CentreRecord:
    c = np.concatenate
    return CentreRecord(
        recs[0].k0, c([r.t for r in recs]), c([r.rows for r in recs], axis=1),
        c([r.tool for r in recs]), c([r.line for r in recs]), c([r.part for r in recs]),
        c([r.override for r in recs]), c([r.vb for r in recs]), recs[0].program,
        [e for r in recs for e in r.events],
    )  # fmt: skip


def steady(rec: CentreRecord | TraceRecord, line: int) -> np.ndarray:
    """Samples of ``line`` of the first part in full engagement, the first and last
    fifth left out."""
    idx = np.flatnonzero((rec.line == line) & (rec.part == 0) & (rec.signal("engaged") > 0.999))
    cut = len(idx) // 5
    return idx[cut : len(idx) - cut]


def line_amplitude(x: np.ndarray, f_hz: float, fs: float) -> float:
    """Amplitude of the component at ``f_hz`` (a single-bin DFT over the samples)."""
    t = np.arange(len(x)) / fs
    return float(2.0 * abs(np.mean((x - x.mean()) * np.exp(-2j * np.pi * f_hz * t))))


def alias(f_hz: float, fs: float) -> float:
    """Where a line at ``f_hz`` lands when sampled at ``fs``."""
    r = f_hz % fs
    return min(r, fs - r)


def rows_machine(params: CentreParams) -> Section:
    """The stated numbers, from the model."""
    blank = MachiningCentre().blank
    f_r, f_a = params.x.mode_hz(blank)
    rows = [
        Row("x.first_mode_hz", f_r, None, "Hz", "two-inertia resonance, the blank clamped"),
        Row("x.antiresonance_hz", f_a, None, "Hz", "motor side"),
        Row("x.stiffness", params.x.stiffness / 1e6, None, "N/um", "screw, nut, bearing, torsion"),
        Row("x.load_mass", params.x.load(blank), None, "kg", "table, fixture, blank"),
        Row("x.motor_mass", params.x.motor_mass, None, "kg", "rotor, coupling, screw / p^2"),
    ]  # fmt: skip
    checks = [Check("x.first_mode_in_40_150_hz", 40.0 <= f_a < f_r <= 150.0, f_r, 150.0)]
    ts = params.sample_time
    for a in "XYZ":
        for loop in ("speed", "position"):
            sys = closed_loop(a, params, loop=loop, workpiece=MachiningCentre().blank)
            rows.append(Row(f"{a.lower()}.{loop}_loop_bandwidth_hz", bandwidth_hz(sys, ts), None,
                            "Hz", "-3 dB of the closed loop"))  # fmt: skip
        # the position loop holds every state of the axis (the speed loop leaves the
        # position free: an eigenvalue at 1 by construction)
        radius = stable(closed_loop(a, params, loop="position", workpiece=MachiningCentre().blank))
        checks.append(Check(f"{a.lower()}.loops_stable", radius < 1.0, radius, 1.0))
    sp = closed_loop("S", params)
    rows.append(Row("spindle.speed_loop_bandwidth_hz", bandwidth_hz(sp, ts), None, "Hz", ""))
    checks.append(Check("spindle.speed_loop_stable", stable(sp) < 1.0, stable(sp), 1.0))
    return rows, checks


def rows_simulated(run: PartRun) -> Section:
    """Z's holding current, the idle power per speed, the part time (seed 0)."""
    m, rec = run.machine, run.full
    z = m.params.z
    still = np.flatnonzero((rec.line == 10) & (rec.t > 0.5) & (rec.part == 0))
    weight = z.load_mass * 9.81 / z.force_constant
    i_z = float(rec.signal("Z.i_m")[still].mean())
    rows = [Row("z.holding_current", i_z, None, "A", f"m g / K_f = {weight:.3f} A")]
    checks = [Check("z.holding_current_is_the_weight", abs(i_z / weight - 1) < 0.01,
                    i_z / weight - 1, 0.01)]  # fmt: skip
    sp = m.params.spindle
    for line, rpm in ((50, 3000.0), (135, 8000.0), (240, 10000.0)):  # feeding in the air
        s = np.flatnonzero((rec.line == line) & (rec.part == 0))[500:]
        p = float(rec.signal("S.power")[s].mean())
        lo, hi = sp.idle_power(rpm), sp.idle_power(rpm, warm=False)
        rows.append(Row(f"spindle.idle_power_{rpm:.0f}rpm", p, None, "W",
                        f"model {lo:.0f} warm - {hi:.0f} cold"))  # fmt: skip
        checks.append(Check(f"spindle.idle_power_{rpm:.0f}rpm_within_model", lo <= p <= hi, p, hi))
    part_s = float(np.flatnonzero(rec.part == 1)[0] * m.sample_time)
    rows.append(Row("part_time", part_s, None, "s", "the default part, 100 % override"))
    return rows, []


def folded_line(x: np.ndarray, f_alias: float, fs: float, factor: int, mode: str) -> float:
    """The line a trace shows at ``f_alias``, predicted from the simulated signal ``x``
    (whole cycles, from a cycle's first sample): the sum of every line at ``m f_tr +-
    f_alias`` below the simulation's Nyquist frequency, each through the trace's own
    transfer (the value at the cycle's last sample, or the cycle's mean), folded back
    (the lines from ``m f_tr - f_alias`` conjugated)."""
    f_tr = fs / factor
    n = np.arange(len(x))
    ts = 1.0 / fs
    total = 0j
    for m in range(int(0.5 * fs / f_tr) + 1):
        for sign in (1.0, -1.0):
            f = m * f_tr + sign * f_alias
            if f <= 0.0 or f >= 0.5 * fs or (m == 0 and sign < 0):
                continue
            c = 2.0 * np.mean((x - x.mean()) * np.exp(-2j * np.pi * f * n * ts))
            if mode == "sample":
                w = np.exp(2j * np.pi * f * (factor - 1) * ts)
            else:
                w = np.mean(np.exp(2j * np.pi * f * np.arange(factor) * ts))
            total += c * w if sign > 0 else np.conj(c * w)
    return float(abs(total))


def spectrum_ratios(run: PartRun) -> dict[str, float]:
    """Per tool and trace mode: the tooth line of Y's current in the 500 Hz trace over the
    lone line at 10 kHz (``gain``) and over the sum of the lines that fold onto it
    (``folded``)."""
    out: dict[str, float] = {}
    fs = 1.0 / run.machine.sample_time
    factor = round(fs / TRACE_HZ)
    y = run.full.signal("Y.i_m")
    for line, tool, rpm, nf in CUTS:
        f_tooth = rpm / 60.0 * nf
        f_a = alias(f_tooth, TRACE_HZ)
        for mode, tr in run.traces.items():
            st = steady(tr, line)
            got = line_amplitude(tr.signal("Y.i_m")[st], f_a, TRACE_HZ)
            # the simulated signal over the same cycles
            k1 = round(tr.t[st[-1]] * fs) + 1
            seg = y[k1 - len(st) * factor : k1]
            out[f"T{tool}.{mode}.gain"] = got / line_amplitude(seg, f_tooth, fs)
            out[f"T{tool}.{mode}.folded"] = got / folded_line(seg, f_a, fs, factor, mode)
    return out


def rows_spectrum(runs: list[PartRun]) -> Section:
    """The tooth lines in the 500 Hz trace over seeds: beside a lone line's theory (1 for a
    point sample, ``|sinc(f / 500)|`` for a cycle mean), and beside the sum of every line
    that folds onto the same frequency (checked: the trace is that sum). Where the
    folded tooth line lands on a spindle line (T3: 2 flutes at 10,000 rpm, 333 Hz folds
    to 167 Hz, the spindle's own frequency) the two cannot be told apart at 500 Hz."""
    per = [spectrum_ratios(r) for r in runs]
    rows, checks = [], []
    for _, tool, rpm, nf in CUTS:
        f = rpm / 60.0 * nf
        at = alias(f, TRACE_HZ)
        f_rev = rpm / 60.0
        where = f"{f:.0f} Hz seen at {at:.0f} Hz"
        if any(abs(at - alias(k * f_rev, TRACE_HZ)) < 0.5 for k in range(1, nf)):
            where += f", on the spindle's {f_rev:.0f} Hz line"
        for mode, theory in (("sample", 1.0), ("mean", abs(float(np.sinc(f / TRACE_HZ))))):
            gain = np.array([p[f"T{tool}.{mode}.gain"] for p in per])
            folded = np.array([p[f"T{tool}.{mode}.folded"] for p in per])
            name = f"trace_500hz.{mode}.tooth_T{tool}"
            rows.append(Row(f"{name}_gain", float(gain.mean()), None, "1",
                            f"{where}; a lone line's theory {theory:.3f}; min {gain.min():.3f} "
                            f"max {gain.max():.3f} over {len(gain)} seeds"))  # fmt: skip
            rows.append(Row(f"{name}_over_folded_sum", float(folded.mean()), None, "1",
                            f"min {folded.min():.3f} max {folded.max():.3f}"))  # fmt: skip
            # the mean over the seeds: one seed's ratio scatters by several % (a point
            # sample folds the whole 10 kHz noise band in)
            err = abs(float(folded.mean()) - 1.0)
            checks.append(Check(f"{name}_is_the_folded_sum", err < 1e-3, err, 1e-3))
    return rows, checks


#: the rapids of the default part, after whose stop the X axis rings
RAPIDS = (30, 70, 120, 160, 220, 260, 270)


def ringing_hz(rec: CentreRecord | TraceRecord, fs: float, seconds: float = 0.1) -> float:
    """The X axis' free ringing after the rapids stop: the peak in 60-240 Hz of the summed
    power spectra of encoder minus scale (the spring's stretch) over ``seconds`` after
    each rapid of the first part."""
    d = rec.signal("X.q_m") - rec.signal("X.q_l")
    n = round(seconds * fs)
    total = np.zeros(2**14 // 2 + 1)
    for line in RAPIDS:
        end = int(np.flatnonzero((rec.line == line) & (rec.part == 0))[-1])
        x = d[end : end + n]
        total += np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x)), 2**14)) ** 2
    f = np.fft.rfftfreq(2**14, 1.0 / fs)
    band = (f > 60.0) & (f < 240.0)
    return float(f[band][np.argmax(total[band])])


def rows_mode(runs: list[PartRun]) -> Section:
    """The X axis' torsion seen by the 500 Hz trace: its ringing after a rapid."""
    m = runs[0].machine
    f_r, f_a = m.params.x.mode_hz(m.blank)
    fs = 1.0 / m.sample_time
    full = np.array([ringing_hz(r.full, fs) for r in runs])
    trace = np.array([ringing_hz(r.traces["sample"], TRACE_HZ) for r in runs])
    rows = [
        Row("x.ringing_hz", float(full.mean()), None, "Hz",
            f"after the rapids, 10 kHz; mode {f_a:.0f}-{f_r:.0f} Hz"),
        Row("trace_500hz.x_ringing_hz", float(trace.mean()), None, "Hz",
            f"the same in the 500 Hz trace; min {trace.min():.1f} max {trace.max():.1f}"),
    ]  # fmt: skip
    err = float(np.max(np.abs(trace - full)))
    ok = err < 3.0 and 0.9 * f_a < full.mean() < 1.1 * f_r
    checks = [Check("trace_500hz.sees_the_x_mode", ok, err, 3.0)]
    return rows, checks


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """The machine's numbers, then ``SEEDS_QUICK`` or ``SEEDS_FULL`` simulated parts."""
    rep = Reproduction(experiment=NAME, source=SOURCE)
    params = CentreParams()
    rep.add(rows_machine(params))
    seeds = SEEDS_QUICK if quick else SEEDS_FULL
    runs = []
    for seed in range(seeds):
        if progress:
            print(f"  part {seed + 1}/{seeds}", flush=True)
        runs.append(simulate_part(seed))
    rep.add(rows_simulated(runs[0]))
    rep.add(rows_spectrum(runs))
    rep.add(rows_mode(runs))
    if plot_dir is not None:
        rep.figures.append(plot_spectrum(runs[0], Path(plot_dir)))
    return rep


def _psd(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude spectrum (Hann window, amplitude-true for a line)."""
    w = np.hanning(len(x))
    a = np.abs(np.fft.rfft((x - x.mean()) * w)) * 2.0 / w.sum()
    return np.fft.rfftfreq(len(x), 1.0 / fs), a


def plot_spectrum(run: PartRun, out_dir: Path) -> str:
    """The figure of the docs page: per signal the 10 kHz spectrum and the 500 Hz traces."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    fs = 1.0 / run.machine.sample_time
    sigs = (("Y.i_m", "Y motor current [A]"), ("S.current", "spindle current [A]"),
            ("X.torsion", "X encoder - scale [um]"))  # fmt: skip
    fig, axes = plt.subplots(3, 2, figsize=(11, 8.5), constrained_layout=True)
    f_tooth = 8000.0 / 60.0 * 3
    for row, (name, label) in enumerate(sigs):
        s = steady(run.full, 140)
        _panel(axes[row, 0], *_psd(_sig(run.full, name)[s], fs), 1000.0, "C0", "simulated, 10 kHz")
        for mode, color in (("sample", "C3"), ("mean", "C2")):
            tr = run.traces[mode]
            st = steady(tr, 140)
            what = "point sample" if mode == "sample" else "cycle mean"
            _panel(axes[row, 1], *_psd(_sig(tr, name)[st], TRACE_HZ), 250.0, color,
                   f"500 Hz trace, {what}")  # fmt: skip
        axes[row, 0].set_ylabel(label)
        for ax, lines in (
            (axes[row, 0], (133.3, f_tooth, 2 * f_tooth)),
            (axes[row, 1], (133.3, 100.0)),
        ):
            for f in lines:
                ax.axvline(f, color="0.6", lw=0.6, ls=":")
    f_r, f_a = run.machine.params.x.mode_hz(run.machine.blank)
    for ax in axes[2]:
        ax.axvspan(f_a, f_r, color="C1", alpha=0.15, lw=0)
    axes[0, 0].set_title("T2 side cut, 8,000 rpm, 3 flutes: simulated signal")
    axes[0, 1].set_title("the same in a 500 Hz CNC trace (Nyquist 250 Hz)")
    for ax in axes[2]:
        ax.set_xlabel("frequency [Hz]")
    note = ("dotted: the spindle (133 Hz) and the teeth (400, 800 Hz; in the trace folded to "
            "100 Hz); shaded: the X axis' mode (112-130 Hz)")  # fmt: skip
    fig.text(0.5, -0.01, note, ha="center")
    path = out_dir / "machining_centre_spectrum.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return str(path)


def _sig(rec: CentreRecord | TraceRecord, name: str) -> np.ndarray:
    if name == "X.torsion":
        return (rec.signal("X.q_m") - rec.signal("X.q_l")) * 1e6
    return rec.signal(name)


def _panel(ax: object, f: np.ndarray, a: np.ndarray, f_max: float, color: str, label: str) -> None:
    keep = f <= f_max
    ax.semilogy(f[keep], np.maximum(a[keep], 1e-7), color=color, lw=0.8, label=label)  # type: ignore[attr-defined]
    ax.set_xlim(0, f_max)  # type: ignore[attr-defined]
    ax.legend(loc="upper right", fontsize=8)  # type: ignore[attr-defined]
    ax.grid(True, which="major", alpha=0.3)  # type: ignore[attr-defined]


__all__ = ["NAME", "SOURCE", "run"]
