"""The global simulation box: bounds (m) and which axes are periodic.

A :class:`Box` is a small immutable value shared by the partition, the halo and the
physics. It knows nothing about particles beyond positions given as ``(N, dim)`` arrays.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class Box:
    """An axis-aligned box ``[lo, hi]`` (m), optionally periodic per axis.

    Parameters
    ----------
    lo, hi : tuple of float
        Lower and upper corner (m); ``len(lo) == len(hi) == dim`` with ``dim`` 2 or 3
        and ``hi > lo`` on every axis. Lists and arrays are converted to tuples.
    periodic : tuple of bool
        One flag per axis; a periodic axis identifies ``lo`` with ``hi``.

    Attributes
    ----------
    dim : int
        Number of axes (2 or 3).
    length : ndarray of float64, shape (dim,)
        ``hi - lo`` (m), a fresh array on each access.
    """

    lo: tuple
    hi: tuple
    periodic: tuple

    def __post_init__(self):
        lo = tuple(float(v) for v in np.asarray(self.lo, dtype=np.float64).reshape(-1))
        hi = tuple(float(v) for v in np.asarray(self.hi, dtype=np.float64).reshape(-1))
        per = tuple(bool(v) for v in np.asarray(self.periodic).reshape(-1))
        if len(lo) not in (2, 3):
            raise ValueError(f"Box: lo has {len(lo)} components; give 2 (2D) or 3 (3D) numbers")
        if len(hi) != len(lo) or len(per) != len(lo):
            raise ValueError(f"Box: lo, hi and periodic have lengths {len(lo)}, {len(hi)}, "
                             f"{len(per)}; give one entry per axis for each")
        if not all(math.isfinite(v) for v in lo + hi):
            raise ValueError(f"Box: bounds lo={lo}, hi={hi} are not all finite; give finite "
                             f"bounds (m)")
        if any(h <= l for l, h in zip(lo, hi)):
            raise ValueError(f"Box: hi={hi} must exceed lo={lo} on every axis; swap or widen "
                             f"the bounds")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "periodic", per)

    @property
    def dim(self) -> int:
        """Number of axes (2 or 3)."""
        return len(self.lo)

    @property
    def length(self) -> np.ndarray:
        """``hi - lo`` (m), shape ``(dim,)``."""
        return np.asarray(self.hi) - np.asarray(self.lo)

    @property
    def any_periodic(self) -> bool:
        """True if at least one axis is periodic."""
        return any(self.periodic)

    def _check(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 0 or x.shape[-1] != self.dim:
            raise ValueError(f"Box: positions of shape {x.shape} do not have {self.dim} "
                             f"components on the last axis; pass an (N, {self.dim}) array (m)")
        return x

    def wrap(self, x) -> np.ndarray:
        """Positions with periodic axes wrapped into ``[lo, hi)``.

        Parameters
        ----------
        x : array_like, shape (..., dim)
            Positions (m).

        Returns
        -------
        ndarray of float64, same shape
            A new array; non-periodic axes are copied unchanged.
        """
        x = np.array(self._check(x), dtype=np.float64, copy=True)
        lo, length = np.asarray(self.lo), self.length
        for axis in range(self.dim):
            if not self.periodic[axis]:
                continue
            r = np.mod(x[..., axis] - lo[axis], length[axis])
            # np.mod may round a tiny negative offset up to exactly ``length``.
            r = np.where(r >= length[axis], r - length[axis], r)
            x[..., axis] = lo[axis] + r
            # lo + r may round up to hi for r just below length.
            hi_axis = self.hi[axis]
            x[..., axis] = np.where(x[..., axis] >= hi_axis, lo[axis], x[..., axis])
        return x

    def outside(self, x) -> np.ndarray:
        """Mask of positions outside the closed box on a non-periodic axis (or NaN).

        Parameters
        ----------
        x : array_like, shape (..., dim)
            Positions (m).

        Returns
        -------
        ndarray of bool, shape ``x.shape[:-1]``
        """
        x = self._check(x)
        flat = np.ascontiguousarray(x.reshape(-1, self.dim))
        out = np.zeros(flat.shape[0], dtype=bool)
        _outside(flat, *self._bounds(), out, False)
        return out.reshape(x.shape[:-1])

    def first_outside(self, x) -> int:
        """Index of the first row of ``x`` (shape (N, dim), m) that :meth:`outside` flags,
        -1 if none: one pass that stops there (the step's state check)."""
        x = self._check(x)
        if x.ndim != 2:
            raise ValueError(f"Box.first_outside: pass an (N, {self.dim}) array, got {x.shape}")
        return int(_outside(x, *self._bounds(), np.zeros(0, dtype=bool), True))

    def _bounds(self):
        return (np.asarray(self.lo), np.asarray(self.hi),
                np.asarray(self.periodic, dtype=np.uint8))

    def image_shifts(self) -> np.ndarray:
        """Offsets (m) of the periodic images of a point, the zero shift first.

        Returns
        -------
        ndarray of float64, shape (3**p, dim)
            Every combination of ``-length, 0, +length`` on the ``p`` periodic axes (0 on
            the others); row 0 is the zero shift.
        """
        axes = [i for i in range(self.dim) if self.periodic[i]]
        length = self.length
        rows = [np.zeros(self.dim)]
        for combo in itertools.product((0, -1, 1), repeat=len(axes)):
            if not any(combo):
                continue
            s = np.zeros(self.dim)
            for axis, k in zip(axes, combo):
                s[axis] = k * length[axis]
            rows.append(s)
        return np.array(rows, dtype=np.float64)

    def minimum_image(self, dx) -> np.ndarray:
        """Displacements (m) with periodic axes mapped to the nearest image.

        Parameters
        ----------
        dx : array_like, shape (..., dim)
            Differences of positions (m).

        Returns
        -------
        ndarray of float64, same shape
            On periodic axes ``dx - length * round(dx / length)``, i.e. in
            ``[-length/2, length/2]``; other axes unchanged.
        """
        dx = np.array(self._check(dx), dtype=np.float64, copy=True)
        length = self.length
        for axis in range(self.dim):
            if self.periodic[axis]:
                dx[..., axis] -= length[axis] * np.round(dx[..., axis] / length[axis])
        return dx


@njit(cache=True, error_model="numpy")
def masked_bounds(x, mask):
    """Per-axis minimum and maximum of the rows of ``x`` with ``mask`` set (``inf`` and
    ``-inf`` if none), without the copy ``x[mask]`` makes."""
    n, dim = x.shape
    lo = np.full(dim, np.inf)
    hi = np.full(dim, -np.inf)
    for i in range(n):
        if mask[i]:
            for a in range(dim):
                lo[a] = min(lo[a], x[i, a])
                hi[a] = max(hi[a], x[i, a])
    return lo, hi


@njit(cache=True, error_model="numpy")
def _outside(x, lo, hi, periodic, out, first):
    """The rule of :meth:`Box.outside` for the rows of ``x``: a non-finite coordinate, or
    one beyond ``[lo, hi]`` on a non-periodic axis. Writes ``out`` (unless ``first``);
    returns the first such row, -1 if none (with ``first`` it stops there)."""
    found = -1
    for i in range(x.shape[0]):
        bad = False
        for k in range(x.shape[1]):
            c = x[i, k]
            if not np.isfinite(c) or (not periodic[k] and not (lo[k] <= c <= hi[k])):
                bad = True
        if bad:
            if found < 0:
                found = i
            if first:
                return found
            out[i] = True
    return found
