r"""What the drives see of a tool's vibration: the chain from the tool to a CNC's trace.

A chatter vibration of the tool at frequency :math:`f` reaches the signals a CNC hands
out through three stages, each a linear factor computed here from the simulator's own
models (the truth side: a detector never sees them):

1. **the structure**: the force the tool modes pass to the spindle housing per unit of
   vibration at the cutting point (:func:`housing_force_per_vibration`): for one mode
   :math:`|k + i\omega c|`, about the modal stiffness — the mode's spring pushes the
   housing as hard as it holds the tool;
2. **the servo loops**: the housing rides on the carriage of a feed axis; the position
   loop answers a force on the carriage with the motor force
   :math:`C P/(1 + C P)` (:func:`axis_force_response`: the closed loop of the position
   response, for the continuous carriage), whole below the loop's bandwidth and falling
   above it; the spindle's speed loop answers a cutting-torque modulation with
   :func:`machine.spindle.torque_response`;
3. **the trace**: a CNC's trace hands out the mean over each sample period :math:`T`
   (a 2 ms mean at 500 Hz): :math:`|\sin(\pi f T)/(\pi f T)|` (:func:`trace_average`),
   which nulls every multiple of the trace rate; then the sampling folds :math:`f` to
   :math:`|f - f_s\,\mathrm{round}(f/f_s)|` (:func:`alias`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.modes import ModalModel
from machine.errors import ParameterError, require_positive
from machine.feed_drives import AxisParams, loop_terms
from machine.spindle import SpindleParams, torque_response


def housing_force(modal: ModalModel, freq_hz: float, q: np.ndarray) -> np.ndarray:
    r"""Complex force on the spindle housing (X, Y) [N] for the complex vibration ``q`` of
    the cutting point [m] at ``freq_hz``.

    The housing receives the cutting force minus what accelerates the tool modes
    (:mod:`machine.regeneration`): :math:`F_b = (I + \omega^2\sum_{tool} m_p u_p u_p^T
    G_p) F` with :math:`q = \Phi F` (least squares when the modes do not span the plane:
    a mode along X alone takes a force along X).
    """
    f = require_positive("freq_hz", freq_hz)
    w = 2.0 * math.pi * f
    t = np.eye(2, dtype=np.complex128)
    for m in modal.modes:
        if m.body == "tool":
            u = np.array(m.direction)
            t += w * w * m.mass * np.outer(u, u) * m.receptance(f)
    force = np.linalg.lstsq(modal.frf(f), np.asarray(q, dtype=np.complex128), rcond=None)[0]
    return np.asarray(t @ force)


def housing_force_per_vibration(modal: ModalModel, freq_hz: float, axis: int = 0) -> float:
    r"""Force on the spindle housing along ``axis`` (0 = X, 1 = Y) per unit vibration of
    the cutting point along it [N/m], the other axis still (:func:`housing_force`); for
    one mode along the axis :math:`|k + i\omega c|`."""
    if axis not in (0, 1):
        raise ParameterError("axis", "0 (X) or 1 (Y)", axis)
    q = np.zeros(2, dtype=np.complex128)
    q[axis] = 1.0
    return float(abs(housing_force(modal, freq_hz, q)[axis]))


def axis_force_response(axis: AxisParams, sample_time: float, freq_hz: float) -> float:
    r"""Motor force per unit force on the carriage at ``freq_hz``.

    The carriage is continuous, the loop sampled: a force on the carriage moves it by
    :math:`P_c(i\omega) = 1/(m(i\omega)^2 + b\,i\omega)`, the PID :math:`C(z)` reads
    that at its samples and answers through the held motor force :math:`P(z)`
    (:func:`machine.feed_drives.loop_terms`): :math:`|C P_c / (1 + C P)|`.
    """
    f = require_positive("freq_hz", freq_hz)
    c, p = loop_terms(axis, sample_time, f)
    s = complex(0.0, 2.0 * math.pi * f)
    pc = 1.0 / (axis.mass * s * s + axis.viscous * s)
    return abs(c * pc / (1.0 + c * p))


def trace_average(freq_hz: float, window_s: float) -> float:
    """Gain of a mean over ``window_s`` at ``freq_hz``: ``|sin(pi f T) / (pi f T)|``."""
    x = math.pi * float(freq_hz) * require_positive("window_s", window_s)
    if x == 0.0:
        return 1.0
    g = abs(math.sin(x) / x)
    # a multiple of the trace rate is an exact null (the sine's rounding leaves ~1e-16)
    return 0.0 if g < 1e-12 else g


def alias(freq_hz: float, rate_hz: float) -> float:
    """Where ``freq_hz`` lands when sampled at ``rate_hz`` (0 .. rate/2)."""
    fs = require_positive("rate_hz", rate_hz)
    return abs(float(freq_hz) - fs * round(float(freq_hz) / fs))


def db(x: float) -> float:
    """``20 log10 |x|`` (-inf for 0)."""
    return 20.0 * math.log10(x) if x > 0 else -math.inf


@dataclass(frozen=True)
class ChainRow:
    """The chain at one chatter frequency (see :func:`attenuation_table`)."""

    freq_hz: float
    structure_n_per_um: float  #: housing force per um of tool vibration
    axis_servo_db: float  #: motor force / force on the carriage
    axis_ma_per_um: float  #: motor current per um of tool vibration (unaveraged)
    spindle_servo_db: float  #: motor torque / cutting torque
    average_2ms_db: float  #: the 500 Hz trace's mean
    average_1ms_db: float  #: the 1 kHz trace's mean
    trace500_ma_per_um: float  #: axis current in a 500 Hz trace, per um
    trace1k_ma_per_um: float  #: axis current in a 1 kHz trace, per um
    alias_500_hz: float
    alias_1k_hz: float


def attenuation_table(
    modal: ModalModel,
    axis: AxisParams,
    sample_time: float,
    spindle: SpindleParams,
    freqs_hz: list[float],
    *,
    direction: int = 0,
) -> list[ChainRow]:
    """The chain of the module docstring at each chatter frequency of ``freqs_hz``."""
    rows = []
    for f in freqs_hz:
        s = housing_force_per_vibration(modal, f, direction)
        g = axis_force_response(axis, sample_time, f)
        a2 = trace_average(f, 2e-3)
        a1 = trace_average(f, 1e-3)
        ma = s * 1e-6 * g / axis.force_constant * 1e3
        rows.append(
            ChainRow(
                freq_hz=float(f),
                structure_n_per_um=s * 1e-6,
                axis_servo_db=db(g),
                axis_ma_per_um=ma,
                spindle_servo_db=db(abs(torque_response(spindle, f, sample_time))),
                average_2ms_db=db(a2),
                average_1ms_db=db(a1),
                trace500_ma_per_um=ma * a2,
                trace1k_ma_per_um=ma * a1,
                alias_500_hz=alias(f, 500.0),
                alias_1k_hz=alias(f, 1000.0),
            )
        )
    return rows


__all__ = [
    "ChainRow",
    "alias",
    "attenuation_table",
    "axis_force_response",
    "db",
    "housing_force",
    "housing_force_per_vibration",
    "trace_average",
]
