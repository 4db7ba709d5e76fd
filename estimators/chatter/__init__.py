"""Milling stability (docs/chatter.md): ``lobes`` (the boundary depth at a speed, the
converged boundary and the chart of both methods) over ``zoa`` (the zero-order approximation
of Altintas and Budak) and ``sd`` (the first-order semi-discretization of Insperger and
Stepan)."""

from estimators.chatter import lobes, sd, zoa

__all__ = ["lobes", "sd", "zoa"]
