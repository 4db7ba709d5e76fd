"""The papers' algorithms and the residual analysis (pure numpy/numba, no I/O).

Imports nothing of ours outside this package and never sees the simulator's truth: each
estimator takes measurements and parameters and returns estimates with diagnostics.
Public names of the cutting force observer and the identifiers are re-exported here; the
other estimators are re-exported as their modules (each with its own ``__all__`` or
documented public functions): ``dfo`` and ``imbdo`` (seed 002), ``esc`` and
``fast_tuner`` (seed 003), ``chatter`` (milling stability: ``chatter.lobes``, the
boundary and the chart, over ``chatter.zoa`` and ``chatter.sd``, the zero-order approximation
and the semi-discretization, docs/chatter.md), ``ud_rls``, ``wear`` (tool wear: seed
004's ``wear.linear``, ``wear.observer`` and ``wear.monitor``, the lathe's and the centre's
wear models), ``idim``, ``residual`` (the residual loop:
``residual.engine``, the one ``analyse`` over a residual model; ``residual.rigid``, the rigid
model; ``residual.families``, its family registry; ``residual.two_inertia``, the observer
model; ``residual.selection``, the decision rule; ``residual.shapes``, shared shape searches;
``residual.cv``, cross-validated figures; ``residual.rate``, what a sampling rate allows),
``monitoring`` (the process monitors: ``monitoring.process``, teach-in limits and event
detectors; ``monitoring.spindle_power``, the spindle's cutting power) and ``observer_effects``.
"""

from estimators import (
    chatter,
    dfo,
    esc,
    fast_tuner,
    idim,
    imbdo,
    monitoring,
    observer_effects,
    residual,
    ud_rls,
    wear,
)
from estimators.errors import EstimatorError, ParameterError
from estimators.filters import DiscreteFilter, discretize, highpass, lowpass
from estimators.force_observer import (
    LoadParams,
    ObserverParams,
    TorsionEstimator,
    TorsionRecord,
    TorsionState,
    cutting_force,
    cutting_force_lagged,
)
from estimators.rls import (
    IdentifierParams,
    IdentRecord,
    IdentState,
    LoadIdentifier,
    RLSParams,
    RLSState,
    excitation_index,
    rls_init,
    rls_update,
)
from estimators.segment_id import (
    SegmentIdentifier,
    SegmentIdentifierParams,
    SegmentRecord,
    SegmentState,
)

__all__ = [
    "DiscreteFilter",
    "EstimatorError",
    "IdentRecord",
    "IdentState",
    "IdentifierParams",
    "LoadIdentifier",
    "LoadParams",
    "ObserverParams",
    "ParameterError",
    "RLSParams",
    "RLSState",
    "SegmentIdentifier",
    "SegmentIdentifierParams",
    "SegmentRecord",
    "SegmentState",
    "TorsionEstimator",
    "TorsionRecord",
    "TorsionState",
    "chatter",
    "cutting_force",
    "cutting_force_lagged",
    "dfo",
    "discretize",
    "esc",
    "excitation_index",
    "fast_tuner",
    "highpass",
    "idim",
    "imbdo",
    "lowpass",
    "monitoring",
    "observer_effects",
    "residual",
    "rls_init",
    "rls_update",
    "ud_rls",
    "wear",
]
