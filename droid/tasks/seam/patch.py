"""The dynamic seam patch (thesis §5.2, Figure 5.4): its positions (:class:`SeamPatch`) and the
segment nearest the tool point (:func:`nearest_segment`; a compiled twin of the same bits is the
kernel's ``seam_nearest``, droid.experiments.seam_kernel)."""
from __future__ import annotations

import numpy as np

from droid.kinematics.transforms import c_einsum

def nearest_segment(tool, a, ab, den, ok) -> tuple[int, np.ndarray]:
    """The patch segment nearest the tool point ``tool`` (3,) [mm]: segment j runs from ``a[j]``
    along ``ab[j]`` (m x 3), ``den[j]`` its squared length (1.0 where ``ok[j]`` is False: too
    short).  The tool point's projection u onto each (0 on a short one), clipped to the segment,
    gives its foot; returns (j, foot j) of the least squared distance (the first of equals)."""
    u = c_einsum("ij,ij->i", tool - a, ab) / den  # np.einsum (optimize=False) without its wrapper
    u = np.clip(np.where(ok, u, 0.0), 0.0, 1.0)
    foot = a + u[:, None] * ab
    off = foot - tool
    d2 = c_einsum("ij,ij->i", off, off)
    j = int(np.argmin(d2))
    return j, foot[j]



class SeamPatch:
    """The seam patch's positions (x, y, z) [mm], index 0 the newest (thesis §5.2: the seam from
    below the camera back to the tool tip): the list of tuples the listing's walk reads
    (``len``, ``patch[i]``), and the same values as one float64 array ``array`` (n x 3), kept
    beside it as points arrive and leave, so thesis mode's search over the whole patch does not
    convert the list every cycle (issue 28 item 2; the same values, the same bits).

    The array is a view into a buffer with room in front of the newest point, so a push writes
    one row instead of copying the patch; beside it each segment j (``array[j+1]`` ->
    ``array[j]``, its vector ``array[j] - array[j+1]`` [mm]) keeps the numbers the search
    divides by, computed once when the segment arrives (:meth:`segments`)."""

    __slots__ = ("points", "_buf", "_seg", "_den", "_ok", "_head", "_n")

    ROOM_ROWS = 1024  # the fewest free rows in front of the newest point after a reallocation

    def __init__(self, points=()) -> None:
        self.points = [tuple(p) for p in points]
        self._place(np.array(self.points, float).reshape(-1, 3))

    def _place(self, arr: np.ndarray) -> None:
        """Copy ``arr`` (n x 3, newest first) into fresh buffers with room in front; the
        segments' numbers are computed for the whole patch at once."""
        n = len(arr)
        head = max(n, self.ROOM_ROWS)
        self._buf = np.empty((head + n, 3))
        self._buf[head:] = arr
        self._seg = np.empty((head + n, 3))
        self._den = np.empty(head + n)
        self._ok = np.empty(head + n, bool)
        self._head, self._n = head, n
        if n > 1:
            self._segments_from(head, n - 1)

    def _segments_from(self, i: int, m: int) -> None:
        """Segments ``i .. i+m-1`` of the buffers: vector, squared length's guard and divisor
        (np.einsum's per-row sums are the same bits for one row as for many)."""
        buf, seg = self._buf, self._seg[i:i + m]
        np.subtract(buf[i:i + m], buf[i + 1:i + m + 1], out=seg)
        l2 = c_einsum("ij,ij->i", seg, seg)
        ok = l2 > 1e-18
        self._ok[i:i + m] = ok
        self._den[i:i + m] = np.where(ok, l2, 1.0)

    @property
    def array(self) -> np.ndarray:
        """The positions [mm] (n x 3, index 0 newest): a view, which later pushes and cuts leave as it is."""
        h = self._head
        return self._buf[h:h + self._n]

    def segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per segment j (from ``array[j+1]`` to ``array[j]``): the vector [mm] (n-1 x 3), the
        divisor (its squared length [mm^2], 1.0 where that is <= 1e-18) and whether it is > 1e-18."""
        h, m = self._head, self._n - 1
        return self._seg[h:h + m], self._den[h:h + m], self._ok[h:h + m]

    def push_front(self, point: tuple) -> None:
        """The newest position becomes index 0."""
        self.points.insert(0, point)
        if self._head == 0:
            self._place(self.array.copy())
        h = self._head = self._head - 1
        self._buf[h] = point
        self._n += 1
        if self._n > 1:
            self._segments_from(h, 1)

    def keep(self, n: int) -> None:
        """Drop everything from index ``n`` on (the oldest)."""
        del self.points[n:]
        self._n = len(self.points)

    def __len__(self) -> int:
        return len(self.points)

    def __getitem__(self, i):
        return self.points[i]
