"""Seed 003: tool eccentricity cancelled by feed-drive modulation (Table 1, Fig. 3).

Two simulated cuts (Table 1 cases 1 and 2: 4 flutes, 10 mm, 20 % radial immersion, up
milling, 80 um/tooth, Al6061) on the X/Y feed drives of :mod:`machine.feed_drives`. The
adaptation starts at 1 s, as in Fig. 3. The extremum seeking controller (seed003 (8)-(16), Table 1
step sizes and perturbations) runs on the dynamometer force; beside it the fast tuner of
:mod:`estimators.fast_tuner` runs on the same cases and through a spindle-speed change.

Definitions used by the rows:

- *cost* J: seed003 (8) on the feed-direction (X) force, one value per revolution;
- *converge time*: time from adaptation start until the cost stays below 10 % of its
  value in the revolution before adaptation starts;
- *cost reduction*: mean cost over the last 2 s divided by that initial cost;
- *force_pp*: peak-to-peak over one revolution of the part of the X force that repeats
  once per revolution but not once per tooth (spindle harmonics 1 .. N_f - 1), i.e. the
  uneven load between flutes that the eccentricity causes; ``before`` is the last
  revolution before adaptation, ``after`` the mean over the last 2 s;
- *cancelling modulation*: the ``(a_m, theta_m)`` whose response through the drives'
  closed loop at the spindle frequency equals minus the eccentricity vector (truth, from
  the drive model; the tuners never see it). The paper's column shows the ideal-drive
  values of seed003 (7): :math:`a_m = \\epsilon`, :math:`\\theta_m = \\theta_\\epsilon + 180`.

This module holds Table 1 (both cases, the ESC beside the fast tuner) and the run that
adds the ablations beside it: the ESC's in :mod:`._seed003_esc_ablations` (why Table 1's
step sizes are slow, doubled gains, mismatched axes, a speed change), the estimated
force's in :mod:`._seed003_observer_ablations` (seed 000's observers, the mass error, the
adaptive observer); the cut and the measures they share in :mod:`._seed003_cut`.
"""

from __future__ import annotations

from pathlib import Path

from machine.milling import MillingParams
from server.experiments.reproduction import Check, Reproduction, Row, Section
from server.experiments.reproductions._seed003_cut import (
    PAPER_CONVERGE_S,
    SECONDS_ESC,
    SECONDS_FAST,
    Summary,
    case_params,
    plot_run,
    run_case,
    summarize,
)
from server.experiments.reproductions._seed003_esc_ablations import (
    esc_diagnosis,
    rows_esc_gains_x2,
    rows_esc_speed_change,
    rows_fast_speed_change,
    rows_mismatch,
)
from server.experiments.reproductions._seed003_observer_ablations import (
    rows_estimated_force,
    rows_estimated_force_adaptive,
    rows_mass_error_leak,
)

NAME = "eccentricity"
SOURCE = "seed 003 (Bahtiyar, Sencer et al.) Table 1, Fig. 3"
ROWS = [
    "case<1|2>.converge_time_s",
    "case<1|2>.cost_reduction",
    "case<1|2>.a_m_um",
    "case<1|2>.theta_m_deg",
    "case<1|2>.a_m_um.cancelling",
    "case<1|2>.theta_m_deg.cancelling",
    "case<1|2>.param_error",
    "case<1|2>.param_converge_time_s",
    "case<1|2>.force_pp.before",
    "case<1|2>.force_pp.after",
    "case<1|2>.esc.revolutions",
    "case<1|2>.fast_tuner.revolutions",
    "case<1|2>.fast_tuner.cost_reduction",
    "case<1|2>.fast_tuner.force_pp.after",
    "case<1|2>.flute_peak_spread.<before|after>",
    "case<1|2>.fast_tuner.flute_peak_spread.<after|ratio>",
    "case<1|2>.fast_tuner.param_error",
    "case1.fast_tuner.speed_change.revolutions",
    "case1.fast_tuner.speed_change.cost_reduction",
    "case1.esc.speed_change.converge_time_s",
    "case<1|2>.esc_gains_x2.<param_converge_time_s|converge_time_s>",
    "case<1|2>.esc.first_rev_response.<radius|phase>",
    "case<1|2>.esc.dither_lag_deg.<radius|phase>",
    "case<1|2>.esc_lag_compensated.param_converge_time_s",
    "case<1|2>.esc_static_cone[_with_lag].param_converge_time_s",
    "case<1|2>.<esc_hpf_0.02|esc_hpf_0.2>.param_converge_time_s",
    "case<1|2>.esc_psi_theta_minus90.param_error",
    "case<1|2>.<esc_drives_30hz|esc_drives_200hz>.param_converge_time_s",
    "case<1|2>.<esc_cost_in_newton|esc_per_revolution>.param_error",
    "case<1|2>.esc.ecc_phase_sweep.<within_15s|within_60s>",
    "case<1|2>.mismatch.<esc|fast_tuner|fast_tuner_ellipse>.residual_1x",
    "case<1|2>.mismatch.fast_tuner_ellipse.revolutions",
    "case1.estimated_force.converge_time_s",
    "case1.estimated_force.cost_reduction",
    "case1.estimated_force[.mass_error_3pct|.current_noise].<param_error|...>",
    "case1.estimated_force.mass_error_3pct.<leak_1x_N|eccentricity_1x_N|leak_ratio|"
    "predicted_param_error|mass_from_1x_motion_error>",
    "case1.estimated_force[.mass_error_<3pct|minus3pct>].adaptive_mass.<converge_time_s|"
    "cost_reduction|param_error|mass_error_<x|y>|mass_time_s|fast_tuner.*>",
    "case1.estimated_force.mass_error_minus3pct.<converge_time_s|cost_reduction|param_error>",
    "case1.estimated_force.adaptive_mass.excitation_<cut_force_N|inertial_force_N|ratio>",
    "case1.estimated_force.ecc_<0|315>deg.<exact|mass_error_3pct|adaptive_mass>.converge_time_s",
    "case1.estimated_force.mass_error_3pct.adaptive_mass.current_noise.<converged|...>",
]


def _esc_case_rows(p: str, c: str, mp: MillingParams, s: Summary) -> list[Row]:
    """A Table 1 case's rows of the ESC (``s``: its summary)."""
    ecc_um = mp.eccentricity * 1e6
    return [
        Row(
            f"{p}.converge_time_s",
            s.converge_time,
            PAPER_CONVERGE_S,
            "s",
            f"{c}; ESC, cost below 10 % of initial and staying",
        ),
        Row(
            f"{p}.cost_reduction",
            s.cost_reduction,
            None,
            "-",
            "ESC; last 2 s / before adaptation",
        ),
        Row(
            f"{p}.a_m_um",
            s.a_um,
            ecc_um,
            "um",
            "ESC at the end; paper column: ideal drives (a_m = eps)",
        ),
        Row(
            f"{p}.theta_m_deg",
            s.theta_deg,
            (mp.eccentricity_deg + 180.0) % 360.0,
            "deg",
            "ESC at the end; paper column: ideal drives (theta_eps + 180)",
        ),
        Row(
            f"{p}.a_m_um.cancelling",
            s.a_star_um,
            None,
            "um",
            "cancels through our drives' gain",
        ),
        Row(
            f"{p}.theta_m_deg.cancelling",
            s.theta_star_deg % 360.0,
            None,
            "deg",
            "cancels through our drives' phase",
        ),
        Row(f"{p}.param_error", s.param_err, None, "-", "ESC |u - u*| / |u*| at the end"),
        Row(
            f"{p}.param_converge_time_s",
            s.param_time,
            PAPER_CONVERGE_S,
            "s",
            "ESC: within 10 % of the cancelling modulation and staying",
        ),
        Row(
            f"{p}.force_pp.before",
            s.pp_before,
            None,
            "N",
            "X force, spindle harmonics 1-3, one revolution",
        ),
        Row(f"{p}.force_pp.after", s.pp_after, None, "N", "ESC, mean over the last 2 s"),
        Row(
            f"{p}.flute_peak_spread.before",
            s.spread_before,
            None,
            "N",
            "highest - lowest flute peak of F_x; before adaptation",
        ),
        Row(
            f"{p}.flute_peak_spread.after",
            s.spread_after,
            None,
            "N",
            "ESC, mean over the last 10 revolutions",
        ),
        Row(
            f"{p}.esc.revolutions",
            s.revolutions,
            None,
            "rev",
            "ESC: revolutions until the cost stays below 10 %",
        ),
    ]


def _fast_tuner_case_rows(p: str, f: Summary, s: Summary) -> list[Row]:
    """A Table 1 case's rows of the fast tuner (``f``), beside the ESC's (``s``)."""
    return [
        Row(
            f"{p}.fast_tuner.revolutions",
            f.revolutions,
            12.5,
            "rev",
            "fast tuner; paper column: best published tuner, 10-15 rev",
        ),
        Row(
            f"{p}.fast_tuner.cost_reduction",
            f.cost_reduction,
            None,
            "-",
            "fast tuner; last 1 s / before adaptation",
        ),
        Row(
            f"{p}.fast_tuner.force_pp.after",
            f.pp_after,
            None,
            "N",
            "fast tuner, mean over the last 1 s",
        ),
        Row(
            f"{p}.fast_tuner.flute_peak_spread.after",
            f.spread_after,
            None,
            "N",
            "fast tuner, mean over the last 10 revolutions",
        ),
        Row(
            f"{p}.fast_tuner.flute_peak_spread.ratio",
            f.spread_after / s.spread_before,
            14.0 / 101.0,
            "-",
            "after / before; paper column: best published tuner 14 N / 101 N",
        ),
        Row(
            f"{p}.fast_tuner.param_error",
            f.param_err,
            None,
            "-",
            "fast tuner |u - u*| / |u*| at the end",
        ),
    ]


def rows_case(case: int, plot_dir: Path | None) -> tuple[Section, list[str]]:
    """One Table 1 case with ESC and with the fast tuner; its figure if ``plot_dir`` is
    given."""
    rows: list[Row] = []
    checks: list[Check] = []
    seconds_esc, seconds_fast = SECONDS_ESC, SECONDS_FAST
    mp = case_params(case)
    tr_esc = run_case(mp, "esc", seconds_esc)
    tr_fast = run_case(mp, "fast", seconds_fast)
    s = summarize(tr_esc, mp)
    f = summarize(tr_fast, mp, tail_s=1.0)
    c = f"case {case}: {mp.spindle_rpm:g} rpm, {mp.axial_depth * 1e3:g} mm"
    p = f"case{case}"
    rows += _esc_case_rows(p, c, mp, s)
    rows += _fast_tuner_case_rows(p, f, s)
    checks += [
        Check(
            f"{p}.esc_within_10pct_of_cancelling_by_15s",
            s.param_time <= 15.0,
            s.param_time,
            15.0,
        ),
        Check(
            f"{p}.fast_tuner_fewer_revolutions_than_esc",
            f.revolutions < s.revolutions,
            f.revolutions,
            s.revolutions,
        ),
        Check(f"{p}.fast_tuner_cost_below_10pct", f.cost_reduction < 0.1, f.cost_reduction, 0.1),
    ]
    figures = []
    if plot_dir is not None:
        figures.append(
            plot_run(Path(plot_dir), f"case{case}", {"ESC": tr_esc, "fast tuner": tr_fast})
        )
    return (rows, checks), figures


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """Both Table 1 cases with ESC and with the fast tuner; checks of issue 6."""
    rep = Reproduction(NAME, SOURCE)
    figures: list[str] = []
    for case in (1, 2):
        section, figs = rows_case(case, plot_dir)
        rep.add(section)
        rep.add(rows_esc_gains_x2(case))
        rep.add((esc_diagnosis(case, SECONDS_ESC + 10.0), []))
        figures += figs
    for case in (1, 2):
        rep.add(rows_mismatch(case))
    rep.add(rows_estimated_force())
    rep.add(rows_mass_error_leak())
    rep.add(rows_estimated_force_adaptive())
    section, figs = rows_fast_speed_change(plot_dir)
    rep.add(section)
    rep.add(rows_esc_speed_change())
    rep.figures += figures + figs
    return rep
