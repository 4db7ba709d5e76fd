"""The real data beside the project: ``../shared/data`` (a worktree sits one level deeper
than the main checkout, so every parent is tried)."""

from __future__ import annotations

from pathlib import Path

TURNING_WEAR = ("turning-wear", "segments.csv")


def shared_file(*parts: str) -> Path | None:
    """``<parent>/shared/data/<parts...>`` for the nearest parent that has it, else None."""
    for p in Path(__file__).resolve().parents:
        f = p.joinpath("shared", "data", *parts)
        if f.exists():
            return f
    return None
