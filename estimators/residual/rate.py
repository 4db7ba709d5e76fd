"""What a record's sampling rate allows: the IDIM pipeline's filter, differentiation and
decimation, the least record length, and which effect families are identifiable at all.

The benchmark's pipeline (EMPS, Janot et al. 2019: 4th-order Butterworth on the position
at 100 Hz, central differences, decimation by 10) is tuned for 1 kHz: the filter sits at a
tenth of the sampling rate and the decimation brings the regression to 100 rows per
second. A record sampled at 1 kHz or faster keeps exactly that pipeline (the numbers of
every kHz log are unchanged). Below 1 kHz the same proportions are kept: the filter at a
tenth of the rate, the decimation to about 100 rows per second (none at 100 Hz and below).

A CNC's data interface typically gives 10 Hz, with the velocity and acceleration the
controller computed from its own fast encoder loop. At such a rate:

* a position quantised to the display resolution (a CNC exports 1 mm at 198 mm) cannot
  be differentiated into a velocity; the controller's velocity and acceleration columns
  are used when the log maps them (``qd_m``, ``qdd_m``) and nothing is filtered;
* only effects that are a static map of the state sampled are identifiable: friction
  against velocity and position (per direction) and a process load on marked rows.
  Inertia (an axis accelerates for tens of ms, one or two samples), cogging and lead
  error (periods of mm pass at tens of Hz at feed speed), time harmonics above the
  Nyquist frequency, and drive delays or lags of a few ms are not: they are not offered,
  each with its reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from estimators.errors import ParameterError
from estimators.idim import IdimParams

#: at or above this rate the benchmark's pipeline is used unchanged [Hz]
BENCHMARK_RATE_HZ = 1000.0
#: below this rate only static-map families (friction, load, slow drift) are offered [Hz]
LOW_RATE_HZ = 100.0
#: the rates the residual loop is made for [Hz]
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 100_000.0
#: the families identifiable below LOW_RATE_HZ: static maps of the sampled state
LOW_RATE_FAMILIES: tuple[str, ...] = (
    "offset",
    "viscous",
    "coulomb_asymmetry",
    "stribeck",
    "position_friction",
    "drift",
    "load",
)


def low_rate_reasons(fs: float) -> dict[str, str]:
    """Why each family a static map cannot show is not identifiable at ``fs`` Hz."""
    ms = 1000.0 / fs
    return {
        "inertia": f"a feed axis accelerates within tens of ms; at {fs:g} Hz ({ms:g} ms per "
        "sample) an acceleration phase is one or two samples, so inertia is not identifiable",
        "position_periodic": f"cogging and lead-error periods (mm) pass at v/period, tens of "
        f"Hz at feed speed: above {fs / 10:g} Hz (a tenth of the sampling rate)",
        "position_harmonics": f"as position_periodic: a period of mm is not resolved at {fs:g} Hz",
        "harmonic": f"a machine vibration lies above the Nyquist frequency {fs / 2:g} Hz",
        "delay": f"a drive's delay of a few ms is below one sample ({ms:g} ms)",
        "drive_delay": f"a drive's delay of a few ms is below one sample ({ms:g} ms)",
        "force_lag": f"a force loop's lag of a few ms is below one sample ({ms:g} ms)",
    }


@dataclass(frozen=True)
class RatePlan:
    """The rate-dependent choices of a rigid residual analysis.

    Attributes
    ----------
    sample_rate : float
        Samples per second [Hz].
    idim : IdimParams
        Position filter and decimation.
    filter_position : bool
        False when the controller's velocity is used (nothing to filter or differentiate
        twice).
    families : tuple of str or None
        The families offered (None: the model's whole registry).
    not_identifiable : dict of str to str
        Families not offered at this rate, with the reason.
    note : str
        One sentence for the report.
    """

    sample_rate: float
    idim: IdimParams
    filter_position: bool = True
    families: tuple[str, ...] | None = None
    not_identifiable: dict[str, str] = field(default_factory=dict)
    note: str = ""


def rate_plan(sample_time: float, *, velocity_given: bool = False) -> RatePlan:
    """The filter, decimation and offered families for a record sampled every
    ``sample_time`` seconds (``velocity_given``: the log maps ``qd_m``).

    Raises
    ------
    ParameterError
        If the rate is outside 1 Hz ... 100 kHz.
    """
    if not (
        isinstance(sample_time, int | float) and math.isfinite(sample_time) and sample_time > 0
    ):
        raise ParameterError("sample_time", "a finite value > 0 [s]", sample_time)
    fs = 1.0 / float(sample_time)
    if not MIN_RATE_HZ <= fs <= MAX_RATE_HZ:
        raise ParameterError(
            "sample_time", f"a rate in {MIN_RATE_HZ:g} ... {MAX_RATE_HZ:g} Hz", sample_time
        )
    if fs >= BENCHMARK_RATE_HZ and not velocity_given:
        return RatePlan(fs, IdimParams(), note="")
    # the benchmark's proportions: filter at fs/10, about 100 regression rows per second
    decimation = max(1, int(round(min(fs, BENCHMARK_RATE_HZ) / 100.0)))
    idim = IdimParams(cutoff_hz=0.1 * fs, decimation=decimation)
    families: tuple[str, ...] | None = None
    reasons: dict[str, str] = {}
    note = f"sampled at {fs:g} Hz: position filter at {0.1 * fs:g} Hz, decimation by {decimation}"
    if velocity_given:
        note = (
            f"sampled at {fs:g} Hz: the controller's velocity (and acceleration) columns are "
            f"used, no position filter; decimation by {decimation}"
        )
    if fs < LOW_RATE_HZ and not velocity_given:
        note += (
            "; map the controller's velocity (qd_m) and acceleration (qdd_m) when the log "
            "has them: a position exported to few digits differentiates poorly"
        )
    if fs < LOW_RATE_HZ:
        families = LOW_RATE_FAMILIES
        reasons = low_rate_reasons(fs)
        note += (
            f". At {fs:g} Hz only static maps are identifiable: friction against velocity "
            "and position, a process load on the marked rows, a slow drift; not inertia, "
            "cogging, vibrations or drive delays (not offered, reasons in not_offered)"
        )
    return RatePlan(fs, idim, not velocity_given, families, reasons, note)


def column_kinematics(
    q: NDArray[np.float64],
    qd: NDArray[np.float64],
    qdd: NDArray[np.float64] | None,
    sample_time: float,
    segments: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.int64], F64, F64, F64, F64]:
    """Kinematics from the controller's velocity (and acceleration) columns.

    Nothing is filtered. Without ``qdd`` the acceleration is the central difference of
    the velocity inside each segment (a run of consecutive rows: ``segments`` holds the
    start index of each), and the jerk likewise from the acceleration; the first and
    last sample of a segment carry one-sided differences and are dropped, as
    :func:`estimators.idim.kinematics` drops the record's ends.

    Returns
    -------
    index, q, qd, qdd, qddd
        The rows kept and the signals on them.
    """
    n = len(q)
    starts = np.asarray([0] if segments is None else segments, dtype=np.int64)
    stops = np.append(starts[1:], n)
    keep: list[NDArray[np.int64]] = []
    acc = np.empty(n)
    jerk = np.empty(n)
    for a, b in zip(starts, stops):
        if qdd is None and b - a < 3:
            continue  # too short to difference: left out
        seg = slice(int(a), int(b))
        acc[seg] = np.gradient(qd[seg], sample_time) if qdd is None else qdd[seg]
        jerk[seg] = np.gradient(acc[seg], sample_time) if b - a >= 2 else 0.0
        keep.append(np.arange(a + 1, b - 1) if qdd is None else np.arange(a, b))
    if not keep:
        raise ParameterError("segments", "a run of at least 3 consecutive rows", 0)
    idx = np.concatenate(keep)
    return idx, q[idx], qd[idx], acc[idx], jerk[idx]
