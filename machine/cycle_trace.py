"""A CNC's trace of a faster signal: one value per position-control cycle.

A CNC hands out its drive signals at the position-control cycle (typically 2 ms or 1 ms:
500 Hz or 1 kHz), while the drive inside runs faster. Two models of what one trace value
is, both without an anti-aliasing filter beyond what the drive itself has:

``point``
    the value at the cycle's tick: the last sample of each cycle of ``factor`` samples
    (what a trace that latches the drive's variables gives; aliases what lies above the
    trace's Nyquist frequency at full amplitude);
``average``
    the mean over the cycle (what a drive that accumulates between ticks gives: a moving
    average of ``factor`` samples, whose sinc response damps, not removes, what lies
    above the Nyquist frequency).

The trace's time of a value is the tick (``point``) or the middle of the cycle
(``average``); either way the trace is uniform at ``factor`` times the sample time.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from common.arrays import F64
from machine.errors import ParameterError

MODELS = ("point", "average")


def trace(values: Mapping[str, F64], factor: int, model: str) -> dict[str, F64]:
    """Each array of ``values`` as the trace sees it (its length a multiple of
    ``factor``; a time array comes out as the tick, or the cycle's middle).

    Raises
    ------
    ParameterError
        An unknown model, a factor < 1, or arrays whose length is not a multiple of it.
    """
    if model not in MODELS:
        raise ParameterError("model", f"one of {list(MODELS)}", model)
    if int(factor) != factor or factor < 1:
        raise ParameterError("factor", "an integer >= 1", factor)
    f = int(factor)
    out: dict[str, F64] = {}
    for name, v in values.items():
        a = np.asarray(v, dtype=np.float64)
        if len(a) % f:
            raise ParameterError(name, f"a length that is a multiple of {f}", len(a))
        groups = a.reshape(-1, f)
        # the cycle's last sample (its tick), or the cycle's mean (time: its middle)
        out[name] = groups[:, -1].copy() if model == "point" else groups.mean(axis=1)
    return out
