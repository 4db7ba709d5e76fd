"""The residual loop: what a drive's measured effort leaves unexplained, and which effects
explain it. ``engine`` (the one ``analyse`` over a residual model), ``rigid`` (the rigid
axis's model, IDIM-LS), ``families`` (its family registry), ``two_inertia`` (the model through
the cutting force observer), ``selection`` (the decision rule), ``shapes`` (shared shape
searches), ``cv`` (cross-validated figures) and ``rate`` (what a record's sampling rate
allows)."""

from estimators.residual import (
    cv,
    engine,
    families,
    rate,
    rigid,
    selection,
    shapes,
    two_inertia,
)

__all__ = [
    "cv",
    "engine",
    "families",
    "rate",
    "rigid",
    "selection",
    "shapes",
    "two_inertia",
]
