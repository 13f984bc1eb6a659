"""IntersectionCount: how many pairs of the cloth's triangles pass through each other, counted exactly during a run
and at its end, for the run summary and the recording (part of a run's bookkeeping, like its speed figures).

A drape can look right and still have a sleeve through the body of the shirt or a fold through itself; the count
says so at a glance. The count is collision.intersections' (exact, triangles sharing no vertex, on the host), which
is independent of the self-collision code. It costs too much for every frame (docs/collision.md, self-collision),
so a run counts at its start, every `every` frames (a quarter of a simulated second by default) and once more at its
end. The largest count is the largest of those: a crossing that opens and closes again between two counts is not seen.
"""
from __future__ import annotations

import numpy as np

from collision.intersections import count_intersecting_pairs

#: simulated seconds between two counts during a run
INTERVAL = 0.25


_last: tuple | None = None  # (positions, triangles, count) of the last count made


def _count(positions, triangles) -> int:
    """count_intersecting_pairs, remembering the last answer: a run's opening count is usually its predecessor's
    closing one (a script running one frame at a time), and comparing the arrays costs far less than counting."""
    global _last
    x, t = np.asarray(positions), np.asarray(triangles)
    if _last is not None and np.array_equal(_last[0], x) and np.array_equal(_last[1], t):
        return _last[2]
    n = count_intersecting_pairs(x, t)
    _last = (x.copy(), t.copy(), n)
    return n


class IntersectionCount:
    """The counts of one run at `fps` frames per simulated second, every `every` frames (default: INTERVAL).

    now:      the last count (None before the first)
    at_start: the first count (the run's start; None before it)
    largest:  the largest count so far, and t_largest [s] when it was seen
    counted:  how many counts were made
    """

    def __init__(self, fps: float, every: int | None = None):
        every = max(1, int(np.round(INTERVAL * fps))) if every is None else int(every)
        if every < 1:
            raise ValueError(f"every must be >= 1 frame, got {every}")
        self.every, self.fps = every, float(fps)
        self.now: int | None = None
        self.at_start: int | None = None
        self.largest, self.t_largest, self.counted = 0, 0.0, 0

    def due(self, frame: int) -> bool:
        """Whether the run counts after `frame` (1-based)."""
        return frame % self.every == 0

    def count(self, positions, triangles, t: float) -> int:
        """Count the intersecting pairs of `triangles` (T,3) over `positions` (P,3) [m] at simulated time t [s], and
        keep the largest."""
        n = _count(positions, triangles)
        self.now, self.counted = n, self.counted + 1
        if self.at_start is None:
            self.at_start = n
        if self.counted == 1 or n > self.largest:
            self.largest, self.t_largest = n, t
        return n

    def describe(self) -> str:
        """The run summary's line, after a final count."""
        return (f"self-intersection: {self.now} intersecting triangle pairs now, at most {self.largest} "
                f"(t = {self.t_largest:.3f} s), {self.at_start} at the start; counted every "
                f"{self.every / self.fps:.3g} s and at the end")
