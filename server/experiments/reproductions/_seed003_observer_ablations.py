"""The seed 003 reproduction's observer ablations: the tuners on an estimated force.

Section 4(a): the cut with the force estimated by seed 000's observers on the X/Y drives
(exact, mass +3 %, current noise); why a 3 % mass error breaks the ESC (the inertial leak
at the spindle frequency); the adaptive observer (mass identified at spindle order
N_f + 1/8) under a nominal mass error, from other eccentricity phases and with current
noise over seeds.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from estimators.esc import spindle_harmonic
from harness.eccentricity_loop import (
    AdaptiveObserverForceSource,
    EccentricityLoop,
    ObserverForceSource,
)
from machine.milling import MillingMachine, MillingParams
from server.experiments.reproduction import Check, Row, Section
from server.experiments.reproductions._seed003_cut import (
    ADAPT_START,
    SECONDS_ESC,
    SECONDS_FAST,
    Summary,
    case_params,
    param_converge_time,
    run_case,
    summarize,
)


def rows_estimated_force() -> Section:
    """4(a): the same cut with the force estimated by observers on the X/Y drives."""
    rows: list[Row] = []
    checks: list[Check] = []
    seconds_esc, seconds_fast = SECONDS_ESC, SECONDS_FAST
    mp = case_params(1)
    for label, me, noise in (
        ("estimated_force", 0.0, 0.0),
        ("estimated_force.mass_error_3pct", 0.03, 0.0),
        ("estimated_force.current_noise", 0.0, 0.05),
    ):
        rng = np.random.default_rng(6)
        obs = ObserverForceSource(
            MillingMachine(mp).drives.params, mass_error=me, current_noise=noise, rng=rng
        )
        tr_e = run_case(mp, "esc", seconds_esc, force_source=obs)
        e = summarize(tr_e, mp)
        obs_f = ObserverForceSource(
            MillingMachine(mp).drives.params, mass_error=me, current_noise=noise, rng=rng
        )
        f = summarize(run_case(mp, "fast", seconds_fast, force_source=obs_f), mp, tail_s=1.0)
        cond = "observer nominal mass " + ("exact" if me == 0 else f"+{me:.0%}")
        if noise > 0:
            cond += f", current noise {noise:g} A rms ({noise * 60:g} N)"
        rows += [
            Row(
                f"case1.{label}.converge_time_s",
                e.converge_time,
                None,
                "s",
                f"ESC on the estimated X force; {cond}; scored on the true force",
            ),
            Row(
                f"case1.{label}.cost_reduction",
                e.cost_reduction,
                None,
                "-",
                f"ESC; {cond}; true cost, last 2 s / before adaptation",
            ),
            Row(f"case1.{label}.param_error", e.param_err, None, "-", f"ESC; {cond}"),
            Row(
                f"case1.{label}.fast_tuner.revolutions",
                f.revolutions,
                None,
                "rev",
                f"fast tuner on the estimated X/Y force; {cond}",
            ),
            Row(
                f"case1.{label}.fast_tuner.cost_reduction",
                f.cost_reduction,
                None,
                "-",
                f"fast tuner; {cond}; true cost",
            ),
        ]
        if label == "estimated_force":
            checks.append(
                Check(
                    "case1.estimated_force_esc_cost_below_10pct",
                    e.cost_reduction < 0.1,
                    e.cost_reduction,
                    0.1,
                )
            )
    return rows, checks


#: the adaptive observer's identification circle [um] (commanded; the carriage moves
#: |G| = 0.65 of it at 82.5 Hz, case 1)
EXCITATION_UM = 1.0
#: seeds of the current-noise rows of the adaptive observer
NOISE_SEEDS = 8


def _settle_phasors(
    mp: MillingParams, mass_error: float, u_um: complex, revs: int = 60
) -> tuple[complex, complex, complex, complex]:
    """Steady cut with the modulation ``u_um`` held (no tuner): 1x phasors over the last
    revolution of the true X force, the fixed observer's estimated X force, the X motor
    force and the X carriage acceleration."""
    m = MillingMachine(mp)
    obs = ObserverForceSource(MillingMachine(mp).drives.params, mass_error=mass_error)
    a, th = abs(u_um) * 1e-6, math.atan2(u_um.imag, u_um.real)
    n = round(m.samples_per_revolution())
    for _ in range(revs):
        rec = m.step(n, a, th)
        fx_hat, _ = obs(rec)
    ts = m.sample_time
    kf = m.drives.params.x.force_constant
    # carriage acceleration by central differences (sample k-1), aligned with its angle
    acc = (rec.x[2:] - 2.0 * rec.x[1:-1] + rec.x[:-2]) / ts**2
    psi = rec.psi[1:-1]
    return (
        spindle_harmonic(rec.fx, rec.psi),
        spindle_harmonic(fx_hat[1:], rec.psi[:-1]),
        spindle_harmonic(rec.ix[1:-1] * kf, psi),
        spindle_harmonic(acc, psi),
    )


def rows_mass_error_leak() -> Section:
    """Why a 3 % observer mass breaks the ESC: the inertial leak at the spindle frequency.

    At the cancelling modulation the carriage circles at 1x with the eccentricity's radius;
    an observer with mass m(1 + d) leaves d m x'' in its estimate, at the same frequency
    and proportional to the modulation. The tuner zeroes the estimated 1x, i.e. the true
    1x plus the leak; with f0 the 1x force without modulation and L the leak at the
    cancelling modulation, the force is affine in the modulation, so the modulation found
    is off by |L / (L - f0)| (the predicted param error).
    """
    mp = case_params(1)
    a_s, th_s = MillingMachine(mp).cancelling_modulation()
    u_star = a_s * 1e6 * complex(math.cos(th_s), math.sin(th_s))
    f0_true, _, tau0, acc0 = _settle_phasors(mp, 0.03, 0j)
    f1_true, f1_est, tau1, acc1 = _settle_phasors(mp, 0.03, u_star)
    leak = f1_est - f1_true
    # a regression of the motor force on the 1x acceleration over the modulation's range
    # (what seed 000's RLS would see here): the cutting force's response to the
    # modulation is folded into the mass
    da, dy = acc1 - acc0, tau1 - tau0
    m_1x = (da.conjugate() * dy).real / abs(da) ** 2
    m_true = MillingMachine(mp).drives.params.x.mass
    p = "case1.estimated_force.mass_error_3pct"
    rows = [
        Row(
            f"{p}.leak_1x_N",
            abs(leak),
            None,
            "N",
            "1x of (estimated - true) X force at the cancelling modulation; fixed observer, "
            "mass +3 %: 0.03 m w^2 x 20 um",
        ),
        Row(
            f"{p}.eccentricity_1x_N",
            abs(f0_true),
            None,
            "N",
            "1x of the true X force without modulation (what the ESC must cancel)",
        ),
        Row(f"{p}.leak_ratio", abs(leak) / abs(f0_true), None, "-", "leak / eccentricity 1x"),
        Row(
            f"{p}.predicted_param_error",
            abs(leak / (leak - f0_true)),
            None,
            "-",
            "|L / (L - f0)|: the modulation error any tuner zeroing the estimated 1x reaches",
        ),
        Row(
            f"{p}.mass_from_1x_motion_error",
            m_1x / m_true - 1.0,
            None,
            "-",
            "mass from the 1x motion (LS of the motor force on x'' between no modulation and "
            "the cancelling one) / true - 1: the cut's response is folded into it",
        ),
    ]
    return rows, []


def _excitation_split(mp: MillingParams, revs: int = 48) -> tuple[float, float]:
    """|true X cutting force| and |m x''| at the excitation order (no modulation, exact
    observer not needed): what the identification sees of the cut against the inertia."""
    from estimators.axis_mass import excitation_order

    m = MillingMachine(mp)
    order = excitation_order(mp.n_flutes, 8)
    n_rev = round(m.samples_per_revolution())
    recs = []
    m.set_excitation(EXCITATION_UM * 1e-6, order)
    for _ in range(revs):
        recs.append(m.step(n_rev))
    last = recs[-8:]
    x = np.concatenate([r.x for r in last])
    fx = np.concatenate([r.fx for r in last])
    psi = np.concatenate([r.psi for r in last])
    acc = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / m.sample_time**2
    e = np.exp(-1j * order * psi)
    k = 2.0 / psi.size
    f_cut = abs(k * np.dot(fx, e))
    inert = abs(k * np.dot(acc, e[1:-1])) * m.drives.params.x.mass
    return float(f_cut), float(inert)


def _adaptive_source(
    mp: MillingParams,
    me: float,
    noise: float = 0.0,
    seed: int = 6,
    stop_after: int | None = None,
) -> AdaptiveObserverForceSource:
    """The adaptive observer's force source on a fresh machine of ``mp``, nominal mass
    error ``me``, the identification circle on."""
    rng = np.random.default_rng(seed)
    return AdaptiveObserverForceSource(
        MillingMachine(mp),
        mass_error=me,
        excitation_um=EXCITATION_UM,
        current_noise=noise,
        rng=rng,
        stop_after=stop_after,
    )


def _rows_fixed_minus3(mp: MillingParams) -> list[Row]:
    """The ESC on the fixed observer's force with the nominal mass 3 % low."""
    fixed_m3 = summarize(
        run_case(
            mp,
            "esc",
            SECONDS_ESC,
            force_source=ObserverForceSource(MillingMachine(mp).drives.params, mass_error=-0.03),
        ),
        mp,
    )
    q = "case1.estimated_force.mass_error_minus3pct"
    return [
        Row(
            f"{q}.converge_time_s",
            fixed_m3.converge_time,
            None,
            "s",
            "ESC on the fixed observer's X force, nominal mass -3 %; true cost",
        ),
        Row(f"{q}.cost_reduction", fixed_m3.cost_reduction, None, "-", "the same; last 2 s"),
        Row(f"{q}.param_error", fixed_m3.param_err, None, "-", "the same"),
    ]


def _rows_adaptive_mass(
    mp: MillingParams, exact: Summary, exact_param_time: float
) -> tuple[list[Row], dict[str, Summary]]:
    """The ESC and the fast tuner on the adaptive observer, nominal mass +3 % and -3 %;
    the ESC's summaries by label (for the checks)."""
    rows: list[Row] = []
    results = {}
    for label, me in (("mass_error_3pct", 0.03), ("mass_error_minus3pct", -0.03)):
        src = _adaptive_source(mp, me)
        tr = run_case(mp, "esc", SECONDS_ESC, force_source=src)
        e = summarize(tr, mp)
        results[label] = e
        src_f = _adaptive_source(mp, me)
        f = summarize(
            run_case(mp, "fast", SECONDS_FAST, force_source=src_f),
            mp,
            tail_s=1.0,
        )
        ex, ey = src.mass_errors()
        p = f"case1.estimated_force.{label}.adaptive_mass"
        cond = (
            f"adaptive observer, nominal mass {me:+.0%}, circle {EXCITATION_UM:g} um at order 4.125"
        )
        rows += [
            Row(
                f"{p}.converge_time_s",
                e.converge_time,
                exact.converge_time,
                "s",
                f"ESC; {cond}; true cost; paper column: exact-mass observer",
            ),
            Row(
                f"{p}.cost_reduction",
                e.cost_reduction,
                exact.cost_reduction,
                "-",
                "the same; last 2 s / before adaptation; paper column: exact mass",
            ),
            Row(
                f"{p}.param_error",
                e.param_err,
                exact.param_err,
                "-",
                "the same; |u - u*| / |u*| at the end; paper column: exact mass",
            ),
            Row(
                f"{p}.param_converge_time_s",
                param_converge_time(tr.loop),
                exact_param_time,
                "s",
                "the same; within 10 % of the cancelling modulation and staying; paper "
                "column: exact mass",
            ),
            Row(
                f"{p}.mass_error_x",
                ex,
                None,
                "-",
                f"identified / true X mass - 1 at the end; {cond}",
            ),
            Row(f"{p}.mass_error_y", ey, None, "-", "the same for Y"),
            Row(
                f"{p}.fast_tuner.revolutions",
                f.revolutions,
                None,
                "rev",
                f"fast tuner on the adaptive observer's X/Y force; {cond}",
            ),
            Row(
                f"{p}.fast_tuner.cost_reduction",
                f.cost_reduction,
                None,
                "-",
                "the same; true cost, last 1 s",
            ),
        ]
    return rows, results


def _rows_identify_then_hold(mp: MillingParams) -> list[Row]:
    """The fast tuner with the mass identified for two windows, then held."""
    # the circle disturbs the fast tuner's one-revolution phasors (order 4.125 leaks into
    # them): identify for two windows (to 1.2 s), then switch the circle off and hold
    src_h = _adaptive_source(mp, 0.03, stop_after=2)
    fh = summarize(run_case(mp, "fast", SECONDS_FAST, force_source=src_h), mp, tail_s=1.0)
    ph = "case1.estimated_force.mass_error_3pct.adaptive_mass.identify_then_hold"
    return [
        Row(
            f"{ph}.fast_tuner.revolutions",
            fh.revolutions,
            None,
            "rev",
            "fast tuner; circle off after 2 identification windows (1.2 s), mass held",
        ),
        Row(f"{ph}.fast_tuner.cost_reduction", fh.cost_reduction, None, "-", "the same"),
        Row(f"{ph}.mass_error_x", src_h.mass_errors()[0], None, "-", "the same; held X mass"),
    ]


def _rows_mass_identification(mp: MillingParams) -> list[Row]:
    """How fast the mass is found, and how the circle's force splits at its order."""
    # how fast the mass is found: first time the X mass stays within 0.5 % of the truth
    src = _adaptive_source(mp, 0.03)
    loop = EccentricityLoop(mp, tuner="off", machine=MillingMachine(mp), force_source=src)
    src.attach(loop.machine)
    t_in = math.inf
    while loop.machine.t < 4.0:
        loop.run_revolutions(1)
        ok = abs(src.mass_errors()[0]) < 0.005
        if ok and not math.isfinite(t_in):
            t_in = loop.machine.t
        elif not ok:
            t_in = math.inf
    rows = [
        Row(
            "case1.estimated_force.mass_error_3pct.adaptive_mass.mass_time_s",
            t_in,
            ADAPT_START,
            "s",
            "time from the start until the identified X mass stays within 0.5 % of the truth "
            "(4 s run); paper column: the ESC's adaptation start",
        )
    ]
    f_cut, inert = _excitation_split(mp)
    rows += [
        Row(
            "case1.estimated_force.adaptive_mass.excitation_cut_force_N",
            f_cut,
            None,
            "N",
            "true X cutting force at order 4.125 with the identification circle on",
        ),
        Row(
            "case1.estimated_force.adaptive_mass.excitation_inertial_force_N",
            inert,
            None,
            "N",
            "m x'' of the X carriage at order 4.125",
        ),
        Row(
            "case1.estimated_force.adaptive_mass.excitation_ratio",
            f_cut / inert,
            None,
            "-",
            "cut / inertial at the identification order: bounds the mass bias",
        ),
    ]
    return rows


def _rows_other_phases(mp: MillingParams) -> list[Row]:
    """The ESC from eccentricity phases 0 and 315 deg: exact, +3 % and adaptive mass."""
    rows: list[Row] = []
    # other eccentricity phases (the ESC converges from these with an exact mass)
    for deg in (0, 315):
        mpd = replace(mp, eccentricity_deg=float(deg))
        for label, src_d in (
            ("exact", ObserverForceSource(MillingMachine(mpd).drives.params)),
            (
                "mass_error_3pct",
                ObserverForceSource(MillingMachine(mpd).drives.params, mass_error=0.03),
            ),
            ("adaptive_mass", _adaptive_source(mpd, 0.03)),
        ):
            sd = summarize(run_case(mpd, "esc", SECONDS_ESC, force_source=src_d), mpd)
            rows.append(
                Row(
                    f"case1.estimated_force.ecc_{deg}deg.{label}.converge_time_s",
                    sd.converge_time,
                    None,
                    "s",
                    f"eccentricity at {deg} deg; ESC on the "
                    + {
                        "exact": "exact-mass observer",
                        "mass_error_3pct": "fixed observer, mass +3 %",
                        "adaptive_mass": "adaptive observer, nominal mass +3 %",
                    }[label],
                )
            )
    return rows


def _rows_current_noise(mp: MillingParams) -> list[Row]:
    """The ESC with current noise over seeds: exact-mass fixed and adaptive observers."""
    rows: list[Row] = []
    # with current noise (0.05 A rms): seeds vary the noise; the exact-mass fixed observer
    # on the same seeds beside it (the ESC's dither freeze makes the cost criterion
    # statistical even with the exact mass)
    pn = "case1.estimated_force.mass_error_3pct.adaptive_mass.current_noise"
    seeds = range(100, 100 + NOISE_SEEDS)
    for label, make in (
        (
            "exact_fixed",
            lambda n: ObserverForceSource(
                MillingMachine(mp).drives.params,
                current_noise=0.05,
                rng=np.random.default_rng(n),
            ),
        ),
        ("adaptive", lambda n: _adaptive_source(mp, 0.03, noise=0.05, seed=n)),
    ):
        ct, pt = [], []
        for seed_n in seeds:
            trn = run_case(mp, "esc", SECONDS_ESC, force_source=make(seed_n))
            ct.append(summarize(trn, mp).converge_time)
            pt.append(param_converge_time(trn.loop))
        what = "exact-mass fixed observer" if label == "exact_fixed" else "adaptive, nominal +3 %"
        rows += [
            Row(
                f"{pn}.{label}.converged",
                float(sum(math.isfinite(t) for t in ct)),
                float(NOISE_SEEDS),
                f"of {NOISE_SEEDS}",
                f"{what}; current noise 0.05 A rms, seeds {seeds[0]}-{seeds[-1]}; cost < 10 % "
                f"and staying by {SECONDS_ESC - ADAPT_START:g} s",
            ),
            Row(
                f"{pn}.{label}.converge_time_s_median",
                float(np.median(ct)),
                None,
                "s",
                "the same; median (inf = not converged)",
            ),
            Row(
                f"{pn}.{label}.param_converged",
                float(sum(math.isfinite(t) for t in pt)),
                float(NOISE_SEEDS),
                f"of {NOISE_SEEDS}",
                "the same; modulation within 10 % of the cancelling one and staying",
            ),
            Row(
                f"{pn}.{label}.param_converge_time_s_median",
                float(np.median(pt)),
                None,
                "s",
                "the same; median",
            ),
        ]
    return rows


def rows_estimated_force_adaptive() -> Section:
    """Issue 13 item 7: the ESC on the force of the adaptive observer (mass identified
    at spindle order N_f + 1/8, :mod:`estimators.axis_mass`) under a nominal mass error."""
    mp = case_params(1)
    tr_exact = run_case(
        mp, "esc", SECONDS_ESC, force_source=ObserverForceSource(MillingMachine(mp).drives.params)
    )
    exact = summarize(tr_exact, mp)
    rows = _rows_fixed_minus3(mp)
    adaptive_rows, results = _rows_adaptive_mass(mp, exact, param_converge_time(tr_exact.loop))
    rows += adaptive_rows
    rows += _rows_identify_then_hold(mp)
    rows += _rows_mass_identification(mp)
    rows += _rows_other_phases(mp)
    rows += _rows_current_noise(mp)
    limit = 1.5 * exact.converge_time
    checks = [
        Check(
            f"case1.estimated_force.{label}.adaptive_converges_within_1.5x_exact",
            e.converge_time <= limit and e.cost_reduction < 0.1,
            e.converge_time,
            limit,
        )
        for label, e in results.items()
    ]
    return rows, checks
