"""When the live loop sends a frame: on a wall schedule of its own, one slot per frame period.

At 1x a block's wall time equals the frame period, so each block gets its frame. The rule
that was here first ("send when a full period has passed since the previous frame went
out") skipped every frame whose block finished a little earlier than the previous one did:
with a few milliseconds of jitter, about every third block went without its frame (~13 Hz
instead of 20 Hz). Slots advance by exactly one period per frame sent (``next += period``),
and a block counts for a slot when it finishes within half a block's wall time before it.

A loop that falls behind (a stall: the process was not scheduled, a slow disk) runs the
blocks it owes back to back; their frames are coalesced into the next one (the stream's
samples stay contiguous: a frame carries every sample since the previous frame), and the
schedule re-anchors on the late block rather than sending a burst of frames to catch up.
"""

from __future__ import annotations


class FrameSlots:
    """The frame schedule of one loop (wall-clock seconds, e.g. ``time.monotonic()``)."""

    def __init__(self, period_s: float, start_s: float) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s: expected a frame period > 0 s, got {period_s!r}")
        self.period_s = period_s
        self.next_s = start_s  # the wall time of the next frame's slot
        # how many times the schedule was moved onto a late block: after a stall at 1x or
        # above; below 1x (a block longer than a period) on every frame
        self.reanchored = 0

    def due(self, done_s: float, block_wall_s: float) -> bool:
        """Whether the block that finished at ``done_s`` (its wall length ``block_wall_s``:
        the block's simulated length over the speed) sends a frame; if it does, the next
        slot is taken."""
        tol = 0.5 * min(block_wall_s, self.period_s)
        if done_s < self.next_s - tol:
            return False
        self.next_s += self.period_s
        if self.next_s < done_s - tol:  # behind by a period or more: re-anchor
            self.next_s = done_s + self.period_s
            self.reanchored += 1
        return True
