"""Struct-of-arrays particle store: owned rows first, halo copies after.

Every field is one numpy array whose first axis is the particle: scalars ``(N,)``,
vectors ``(N, dim)``, tensors ``(N, dim, dim)``. Physics loops over ``[:n_owned]``;
rows ``n_owned:`` are halo copies refreshed by :mod:`decomposition.halo`. ``id`` (int64)
is global and stable for a particle's life.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Fields every particle has: name -> (trailing shape as a function of dim, dtype).
CORE_FIELDS = {
    "id": (lambda dim: (), np.int64),
    "x": (lambda dim: (dim,), np.float64),
    "v": (lambda dim: (dim,), np.float64),
    "m": (lambda dim: (), np.float64),
    "phase": (lambda dim: (), np.uint8),
    "material": (lambda dim: (), np.int16),
    "body": (lambda dim: (), np.int16),
}


#: The phase codes of the ``phase`` field (section 3.3: a solid becomes a fluid).
PHASE_SOLID, PHASE_FLUID, PHASE_WALL = 0, 1, 2


def max_speed(v, n, flags=None, value=1) -> float:
    """The largest speed |v| (m/s) of the first ``n`` rows of ``v`` whose ``flags`` equal
    ``value`` (all of them without ``flags``); 0 if there are none. One pass, no
    temporaries: a CFL limit (eq. (49)) is taken every step by each stage, and the numpy
    form had cost 20-30 us each in a 2D coupled step of 1,100 particles."""
    if flags is None:
        return _max_speed(v, n, np.zeros(0, dtype=np.uint8), 0)
    return _max_speed(v, n, flags, value)


@njit(cache=True, error_model="numpy")
def _max_speed(v, n, flags, value):
    every = flags.shape[0] == 0
    top = 0.0
    for i in range(n):
        if every or flags[i] == value:
            s = 0.0
            for k in range(v.shape[1]):
                s += v[i, k] * v[i, k]
            top = max(top, s)
    return math.sqrt(top)


class ParticleSet:
    """Named arrays of one rank's particles.

    Parameters
    ----------
    dim : int
        2 or 3.
    fields : dict of str to ndarray
        Owned rows only; all arrays have the same first dimension.
    """

    def __init__(self, dim: int, fields: dict):
        self.dim = dim
        self.data = {}
        self.n_owned = 0
        self.n_halo = 0
        self.set_owned(fields)

    # -- rows
    @property
    def n_total(self) -> int:
        return self.n_owned + self.n_halo

    def set_owned(self, fields: dict) -> None:
        """Replace all rows with ``fields`` (owned only; the halo is dropped)."""
        lengths = {len(a) for a in fields.values()}
        if len(lengths) > 1:
            raise ValueError(f"particle fields of unequal length: "
                             f"{ {k: len(a) for k, a in fields.items()} }")
        self.data = {k: np.ascontiguousarray(a) for k, a in fields.items()}
        self.n_owned = lengths.pop() if lengths else 0
        self.n_halo = 0

    def set_halo(self, halo: dict) -> None:
        """Append halo rows; fields absent from ``halo`` get zero rows.

        The owned rows are not copied: a field whose array has room after them (the
        array of the last step's halo, when no row changed rank) takes the halo rows in
        place; otherwise a new array is made, with room for an eighth more halo rows.
        Copying every field's owned rows each step had cost 12 ms per step of a 3D
        coupled tank of 112,761 particles on 2 ranks (docs/performance.md)."""
        n = len(next(iter(halo.values()))) if halo else 0
        own_n, total = self.n_owned, self.n_owned + n
        for name, arr in self.data.items():
            own = arr[:own_n]
            if n == 0:  # no halo (one rank, or isolated): no copy of the owned rows
                self.data[name] = own
                continue
            buf = _room_after(own, total)
            if buf is None:
                buf = np.empty((total + n // 8,) + own.shape[1:], dtype=own.dtype)
                buf[:own_n] = own
            extra = halo.get(name)
            buf[own_n:total] = 0 if extra is None else extra
            self.data[name] = buf[:total]
        self.n_halo = n

    def owned_fields(self, names=None) -> dict:
        names = self.data.keys() if names is None else names
        return {k: self.data[k][: self.n_owned] for k in names}

    # -- fields
    def add_field(self, name: str, shape=(), dtype=np.float64, fill=0) -> np.ndarray:
        """Allocate a field (all rows) if absent; return it."""
        if name not in self.data:
            self.data[name] = np.full((self.n_total,) + tuple(shape), fill, dtype=dtype)
        return self.data[name]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name]

    def __setitem__(self, name: str, value: np.ndarray) -> None:
        if len(value) != self.n_total:
            raise ValueError(f"field '{name}' has {len(value)} rows, the set has {self.n_total}")
        self.data[name] = value

    def __contains__(self, name: str) -> bool:
        return name in self.data

    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.data.values())


def _room_after(own: np.ndarray, total: int):
    """The writable array whose first rows ``own`` is (same dtype and row shape), if it
    has at least ``total`` rows; else None."""
    base = own.base if own.base is not None else own
    if (isinstance(base, np.ndarray) and base.flags.c_contiguous and base.flags.writeable
            and base.dtype == own.dtype and base.shape[1:] == own.shape[1:]
            and base.shape[0] >= total
            and base.__array_interface__["data"][0] == own.__array_interface__["data"][0]):
        return base
    return None
