"""The papers' algorithms and the residual analysis (pure numpy/numba, no I/O).

Imports nothing of ours outside this package and never sees the simulator's truth: each
estimator takes measurements and parameters and returns estimates with diagnostics.
Public names of the cutting force observer and the identifiers are re-exported here; the
other estimators (IMBDO, DFO, ESC, wear observer, residual analysis) live in their own
modules.
"""

from estimators.errors import EstimatorError, ParameterError
from estimators.filters import DiscreteFilter, discretize, highpass, lowpass
from estimators.force_observer import (
    LoadParams,
    ObserverParams,
    TorsionEstimator,
    TorsionRecord,
    TorsionState,
    cutting_force,
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
    "TorsionEstimator",
    "TorsionRecord",
    "TorsionState",
    "cutting_force",
    "discretize",
    "excitation_index",
    "highpass",
    "lowpass",
    "rls_init",
    "rls_update",
]
