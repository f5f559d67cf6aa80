"""Recursive coordinate bisection (RCB) of the global box among the ranks.

Notes
-----
The tree is built level by level. At each level every group of ranks that still has
more than one rank is split into a left group of ``floor(n/2)`` ranks and a right group
of ``ceil(n/2)`` ranks (so any rank count works, not only powers of two):

1. One ``Allreduce`` gives, per group, the global particle count, the total (integer)
   weight and the particle bounding box. The cut axis ``a`` is the longest extent of
   that bounding box (of the group's region if the group has no particle; ties go to
   the lowest axis).
2. Particles are ordered lexicographically by ``(x[a], x[a+1], ..., x[a+dim-1])``
   (axes mod dim), so coincident coordinates on the cut axis (a regular lattice) are
   still split at an exact particle count. The cut is a point ``c``; a position goes
   left iff its key is lexicographically smaller than ``c``'s. The left group receives
   the weight closest to ``W * n_left / n`` (unweighted: ``round(N * n_left / n)``
   particles, halves rounded down), which balances the final counts within one
   particle when all positions are distinct.
3. ``c`` is found by a 16-way search over the order-preserving int64 images of the
   float64 coordinates, one key component at a time; each round evaluates 16 pivots
   per group locally (``searchsorted`` in pre-sorted segments) and sums the counts over
   ranks with one vectorised ``Allreduce`` for all groups of the level. A component
   needs at most ~16 rounds; later components only matter for ties.

All reductions are over integers or exact minima/maxima, and weights are first
rounded to integers relative to the global maximum, so the cuts depend only on the
global set of positions (and weights), not on how they are distributed or ordered.
The sub-box of a rank is the intersection of the half-spaces on its path, clipped to
the global box; every owned position lies in its owner's *closed* sub-box.
"""
from __future__ import annotations

import numpy as np
from mpi4py import MPI
from numba import njit

from decomposition.box import Box
from decomposition.comm import raise_if_any

_FLIP = np.int64(0x7FFFFFFFFFFFFFFF)
_WAYS = 16


def _ordered(x) -> np.ndarray:
    """int64 keys with the order of the float64 values (-0.0 equals +0.0)."""
    b = (np.asarray(x, dtype=np.float64) + 0.0).view(np.int64)
    return np.where(b < 0, b ^ _FLIP, b)


def _unordered(k) -> np.ndarray:
    """Inverse of :func:`_ordered`."""
    k = np.asarray(k, dtype=np.int64)
    return np.ascontiguousarray(np.where(k < 0, k ^ _FLIP, k)).view(np.float64)


def _permute(a: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Columns of ``a`` (n, d) reordered per row to ``axis, axis+1, ...`` (mod d)."""
    d = a.shape[1]
    cols = (axis[:, None] + np.arange(d)) % d
    return np.take_along_axis(a, cols, axis=1)


def _lex_less(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise lexicographic ``a < b`` of two (n, d) arrays."""
    d = a.shape[1]
    less = a[:, d - 1] < b[:, d - 1]
    for s in range(d - 2, -1, -1):
        less = (a[:, s] < b[:, s]) | ((a[:, s] == b[:, s]) & less)
    return less


@njit(cache=True, error_model="numpy")
def _descend(x, axis, cut, child, rank, out):
    """Owner of each row of ``x``: walk the tree from the root, at each inner node
    comparing the point with the cut lexicographically from the node's axis on (the
    order of :func:`_lex_less` on :func:`_permute`-d rows)."""
    n, dim = x.shape
    for i in range(n):
        node = 0
        while axis[node] >= 0:
            a = axis[node]
            side = 1  # right unless x < cut in the rotated lexicographic order
            for s in range(dim):
                c = (a + s) % dim
                if x[i, c] < cut[node, c]:
                    side = 0
                    break
                if x[i, c] > cut[node, c]:
                    break
            node = child[node, side]
        out[i] = rank[node]
    return out


def _allreduce(comm, a: np.ndarray, op) -> np.ndarray:
    a = np.ascontiguousarray(a)
    out = np.empty_like(a)
    comm.Allreduce(a, out, op=op)
    return out


def _select(comm, keys, group, vals, target, active, n_groups) -> np.ndarray:
    """Per group, the smallest key ``t`` with ``sum(vals[key <= t]) >= target`` (collective).

    ``keys`` (n, d) int64 are lexicographic keys, ``group`` (n,) the group of each row,
    ``vals`` (n,) int64 >= 0, ``target`` (G,) int64 >= 1, ``active`` (G,) bool (the same on
    every rank). Returns (G, d) int64 (rows of inactive groups are 0).
    """
    d = keys.shape[1]
    result = np.zeros((n_groups, d), dtype=np.int64)
    need = target.astype(np.int64).copy()
    cand = active[group] if len(group) else np.zeros(0, dtype=bool)
    ways = np.arange(_WAYS, dtype=np.uint64)
    rows = np.arange(n_groups)
    for s in range(d):
        kc, gc, vc = keys[cand, s], group[cand], vals[cand]
        order = np.lexsort((kc, gc))
        kc, gc, vc = kc[order], gc[order], vc[order]
        starts = np.searchsorted(gc, np.arange(n_groups + 1))
        csum = np.concatenate(([0], np.cumsum(vc, dtype=np.int64)))
        filled = np.nonzero(starts[1:] > starts[:-1])[0]

        def local_sums(pivots, side):
            out = np.zeros(pivots.shape, dtype=np.int64)
            for gi in filled:  # loop over groups (at most the rank count)
                a, b = starts[gi], starts[gi + 1]
                pos = np.searchsorted(kc[a:b], pivots[gi], side=side)
                out[gi] = csum[a + pos] - csum[a]
            return out

        # Global min and max key per group: MAX over [max, ~min] (~ reverses order).
        ext = np.full(2 * n_groups, np.iinfo(np.int64).min, dtype=np.int64)
        ext[filled] = kc[starts[filled + 1] - 1]
        ext[n_groups + filled] = ~kc[starts[filled]]
        ext = _allreduce(comm, ext, MPI.MAX)
        hi, lo = ext[:n_groups], ~ext[n_groups:]
        live = active & (hi >= lo)
        lo = np.where(live, lo, 0)
        hi = np.where(live, hi, 0)
        while True:
            open_ = lo < hi
            if not open_.any():
                break
            span = hi.astype(np.uint64) - lo.astype(np.uint64)
            q, r = span // np.uint64(_WAYS), span % np.uint64(_WAYS)
            piv = (lo.astype(np.uint64)[:, None] + q[:, None] * ways
                   + (r[:, None] * ways) // np.uint64(_WAYS)).astype(np.int64)
            ok = _allreduce(comm, local_sums(piv, "right"), MPI.SUM) >= need[:, None]
            has = ok.any(axis=1)
            j = np.argmax(ok, axis=1)
            new_hi = np.where(has, piv[rows, j], hi)
            new_lo = np.where(has, np.where(j > 0, piv[rows, np.maximum(j - 1, 0)] + 1, lo),
                              piv[:, _WAYS - 1] + 1)
            lo = np.where(open_, new_lo, lo)
            hi = np.where(open_, new_hi, hi)
        result[:, s] = lo
        if s + 1 < d:
            below = _allreduce(comm, local_sums(lo[:, None], "left")[:, 0], MPI.SUM)
            need = need - below
            sub = np.nonzero(cand)[0]
            cand[sub] = keys[sub, s] == lo[group[sub]]
    return result


def _regions(box: Box, axis, cut, child):
    """Closed region (lo, hi) of every node, top-down, clipped to the box."""
    n_nodes, dim = cut.shape
    lo = np.zeros((n_nodes, dim))
    hi = np.zeros((n_nodes, dim))
    lo[0], hi[0] = box.lo, box.hi
    for node in range(n_nodes):  # parents precede children (breadth-first numbering)
        a = int(axis[node])
        if a < 0:
            continue
        c = min(max(cut[node, a], lo[node, a]), hi[node, a])
        left, right = child[node]
        lo[left], hi[left] = lo[node], hi[node]
        lo[right], hi[right] = lo[node], hi[node]
        hi[left, a] = c
        lo[right, a] = c
    return lo, hi


class RCB:
    """A recursive coordinate bisection replicated on every rank.

    Build it collectively with :meth:`RCB.build`, or rebuild it exactly from stored
    arrays with :meth:`RCB.from_arrays`. See the module Notes for the algorithm.
    ``box(rank)`` is an alias of :meth:`subbox`.

    Attributes
    ----------
    domain : Box
        The global box.
    n_ranks : int
        Number of leaves (the rank count it was built for).
    depth : int
        Number of levels of cuts.
    """

    _KEYS = ("box_lo", "box_hi", "box_periodic", "axis", "cut", "child", "rank")

    def __init__(self, box: Box, axis, cut, child, rank):
        self.domain = box
        self._axis = np.asarray(axis, dtype=np.int8).reshape(-1)
        n_nodes = self._axis.shape[0]
        self._cut = np.asarray(cut, dtype=np.float64).reshape(n_nodes, box.dim)
        self._child = np.asarray(child, dtype=np.int32).reshape(n_nodes, 2)
        self._rank = np.asarray(rank, dtype=np.int32).reshape(n_nodes)
        leaves = self._axis < 0
        self.n_ranks = int(leaves.sum())
        if (n_nodes != 2 * self.n_ranks - 1
                or not np.array_equal(np.sort(self._rank[leaves]), np.arange(self.n_ranks))
                or np.any(self._child[~leaves] <= np.nonzero(~leaves)[0][:, None])
                or np.any(self._child[~leaves] >= n_nodes)
                or np.any(self._axis >= box.dim)):
            raise ValueError("RCB: the tree arrays are inconsistent (leaf ranks, children or "
                             "axes); rebuild the partition with RCB.build or pass the arrays "
                             "written by to_arrays unchanged")
        depth = np.zeros(n_nodes, dtype=np.int64)
        for node in np.nonzero(~leaves)[0]:
            depth[self._child[node]] = depth[node] + 1
        self.depth = int(depth.max())
        lo, hi = _regions(box, self._axis, self._cut, self._child)
        self._sub_lo = np.zeros((self.n_ranks, box.dim))
        self._sub_hi = np.zeros((self.n_ranks, box.dim))
        self._sub_lo[self._rank[leaves]] = lo[leaves]
        self._sub_hi[self._rank[leaves]] = hi[leaves]

    # ------------------------------------------------------------------ build
    @classmethod
    def build(cls, comm, x_owned, box: Box, weights=None) -> "RCB":
        """Collective: partition the global set of positions among ``comm.size`` ranks.

        Parameters
        ----------
        comm : mpi4py.MPI.Comm
            Every rank calls, also ranks that own no particle.
        x_owned : array_like, shape (n, dim)
            Positions (m) owned by this rank, finite, normally inside ``box`` (wrap
            periodic axes first with :meth:`Box.wrap`).
        box : Box
            The global box; sub-boxes are clipped to it.
        weights : array_like, shape (n,), optional
            Non-negative finite work estimate per particle; the left/right weight
            totals are made proportional to the group sizes. Weights are rounded to
            integers relative to the global maximum (about 2**-52 relative); a group
            whose weights are all zero is split by count. Default: count particles.

        Returns
        -------
        RCB
            The same tree on every rank.

        Raises
        ------
        ValueError
            On every rank, if on any rank the positions have the wrong shape or are not
            finite, or the weights have the wrong shape or are negative or not finite.
        """
        dim = box.dim
        x = np.asarray(x_owned, dtype=np.float64)
        error = None
        if x.ndim != 2 or x.shape[1] != dim:
            error = ValueError(f"RCB.build: positions have shape {x.shape}; pass an "
                               f"(n, {dim}) array (m) for this {dim}D box")
        elif not np.isfinite(x).all():
            error = ValueError("RCB.build: positions contain NaN or inf; check the state "
                               "before re-partitioning")
        w = None
        if error is None and weights is not None:
            w = np.asarray(weights, dtype=np.float64).reshape(-1)
            if w.shape[0] != x.shape[0] or not np.isfinite(w).all() or (w < 0).any():
                error = ValueError(f"RCB.build: weights must be {x.shape[0]} finite "
                                   f"non-negative numbers (one per owned row); got shape "
                                   f"{w.shape}")
        raise_if_any(comm, error)
        size = comm.size
        n = x.shape[0]

        if w is None:
            vals = np.ones(n, dtype=np.int64)
        else:
            w_max = comm.allreduce(float(w.max()) if n else 0.0, op=MPI.MAX)
            n_total = comm.allreduce(n, op=MPI.SUM)
            if w_max == 0.0:
                vals = np.ones(n, dtype=np.int64)
            else:
                bits = min(52, 62 - int(n_total).bit_length())
                vals = np.floor(w / w_max * 2.0 ** bits + 0.5).astype(np.int64)

        axis_l, cut_l, child_l, rank_l = [-1], [np.zeros(dim)], [(-1, -1)], [-1]
        first, nrank = [0], [size]
        reg_lo, reg_hi = [np.array(box.lo)], [np.array(box.hi)]
        node_of = np.zeros(n, dtype=np.int64)
        pending = [0] if size > 1 else []
        if size == 1:
            rank_l[0] = 0
        while pending:
            g_of_node = np.full(len(axis_l), -1, dtype=np.int64)
            g_of_node[pending] = np.arange(len(pending))
            g = g_of_node[node_of]
            ranks_n = np.array([nrank[p] for p in pending], dtype=np.int64)
            ranks_l = ranks_n // 2
            region = (np.array([reg_lo[p] for p in pending]),
                      np.array([reg_hi[p] for p in pending]))
            axes, cuts = _level_cuts(comm, x, vals, g, ranks_n, ranks_l, region,
                                     weighted=w is not None)
            new_pending = []
            left_id = np.zeros(len(pending), dtype=np.int64)
            right_id = np.zeros(len(pending), dtype=np.int64)
            for gi, p in enumerate(pending):  # loop over groups of ranks
                a = int(axes[gi])
                axis_l[p], cut_l[p] = a, cuts[gi]
                c = min(max(cuts[gi, a], reg_lo[p][a]), reg_hi[p][a])
                kids = []
                for lo_rank, k in ((first[p], int(ranks_l[gi])),
                                   (first[p] + int(ranks_l[gi]), int(ranks_n[gi] - ranks_l[gi]))):
                    kid = len(axis_l)
                    kids.append(kid)
                    axis_l.append(-1)
                    cut_l.append(np.zeros(dim))
                    child_l.append((-1, -1))
                    rank_l.append(lo_rank if k == 1 else -1)
                    first.append(lo_rank)
                    nrank.append(k)
                    reg_lo.append(reg_lo[p].copy())
                    reg_hi.append(reg_hi[p].copy())
                    if k > 1:
                        new_pending.append(kid)
                reg_hi[kids[0]][a] = c
                reg_lo[kids[1]][a] = c
                child_l[p] = tuple(kids)
                left_id[gi], right_id[gi] = kids
            sel = np.nonzero(g >= 0)[0]
            gs = g[sel]
            less = _lex_less(_permute(x[sel], axes[gs]), _permute(cuts[gs], axes[gs]))
            node_of[sel] = np.where(less, left_id[gs], right_id[gs])
            pending = new_pending
        return cls(box, np.array(axis_l), np.array(cut_l), np.array(child_l), np.array(rank_l))

    # ---------------------------------------------------------------- queries
    def owner(self, x) -> np.ndarray:
        """Owner rank of each position (local, pure, vectorised).

        Parameters
        ----------
        x : array_like, shape (N, dim)
            Positions (m); wrap periodic axes into the box first. Positions outside the
            box go to the rank whose sub-box extends towards them.

        Returns
        -------
        ndarray of int32, shape (N,)
        """
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.domain.dim:
            raise ValueError(f"RCB.owner: positions have shape {x.shape}; pass an "
                             f"(N, {self.domain.dim}) array (m)")
        return _descend(np.ascontiguousarray(x), self._axis, self._cut, self._child,
                        self._rank, np.empty(x.shape[0], dtype=np.int32))

    def subbox(self, rank: int):
        """Closed sub-box of ``rank``: ``(lo, hi)`` float64 arrays (m), clipped to the box.

        A rank owning nothing may get a degenerate (zero-width) sub-box.
        """
        rank = int(rank)
        if not 0 <= rank < self.n_ranks:
            raise ValueError(f"RCB.subbox: rank {rank} is not in [0, {self.n_ranks}); the "
                             f"partition was built for {self.n_ranks} ranks")
        return self._sub_lo[rank].copy(), self._sub_hi[rank].copy()

    box = subbox  # the name used in docs/architecture.md

    def subboxes(self):
        """All sub-boxes at once: ``(lo, hi)``, each of shape (n_ranks, dim) (m)."""
        return self._sub_lo.copy(), self._sub_hi.copy()

    @staticmethod
    def imbalance(comm, n_owned: int) -> float:
        """Collective: max/mean of the owned counts (see :func:`imbalance`)."""
        return imbalance(comm, n_owned)

    # -------------------------------------------------------------- storage
    def to_arrays(self) -> dict:
        """The tree as plain numpy arrays (for HDF5); :meth:`from_arrays` inverts it.

        Returns
        -------
        dict of str to ndarray
            ``box_lo``, ``box_hi`` (dim,) float64 (m); ``box_periodic`` (dim,) int8;
            ``axis`` (nodes,) int8 (-1 for a leaf); ``cut`` (nodes, dim) float64 (m);
            ``child`` (nodes, 2) int32; ``rank`` (nodes,) int32 (-1 for inner nodes).
        """
        return {"box_lo": np.array(self.domain.lo, dtype=np.float64),
                "box_hi": np.array(self.domain.hi, dtype=np.float64),
                "box_periodic": np.array(self.domain.periodic, dtype=np.int8),
                "axis": self._axis.copy(), "cut": self._cut.copy(),
                "child": self._child.copy(), "rank": self._rank.copy()}

    @classmethod
    def from_arrays(cls, arrays) -> "RCB":
        """Rebuild exactly the tree stored by :meth:`to_arrays` (local, no communication).

        Parameters
        ----------
        arrays : mapping of str to array_like
            A dict or an h5py group with the keys of :meth:`to_arrays`.
        """
        missing = [k for k in cls._KEYS if k not in arrays]
        if missing:
            raise ValueError(f"RCB.from_arrays: missing {missing}; pass the dict written by "
                             f"RCB.to_arrays")
        a = {k: np.asarray(arrays[k]) for k in cls._KEYS}
        box = Box(tuple(a["box_lo"].tolist()), tuple(a["box_hi"].tolist()),
                  tuple(bool(v) for v in a["box_periodic"].tolist()))
        return cls(box, a["axis"], a["cut"], a["child"], a["rank"])


def _level_cuts(comm, x, vals, g, ranks_n, ranks_l, region, weighted):
    """Cut axis (G,) and cut point (G, dim) of every group of one level (collective)."""
    n_groups = len(ranks_n)
    dim = x.shape[1]
    sel = np.nonzero(g >= 0)[0]
    gs, xs, vs = g[sel], x[sel], vals[sel]
    order = np.argsort(gs, kind="stable")
    starts = np.searchsorted(gs[order], np.arange(n_groups + 1))
    csum = np.concatenate(([0], np.cumsum(vs[order], dtype=np.int64)))
    ints = np.zeros(2 * n_groups, dtype=np.int64)
    ints[:n_groups] = np.diff(starts)
    ints[n_groups:] = csum[starts[1:]] - csum[starts[:-1]]
    ext = np.full((2, n_groups, dim), -np.inf)
    for gi in np.nonzero(ints[:n_groups])[0]:  # loop over groups
        seg = xs[order[starts[gi]:starts[gi + 1]]]
        ext[0, gi], ext[1, gi] = seg.max(axis=0), -seg.min(axis=0)
    ints = _allreduce(comm, ints, MPI.SUM)
    ext = _allreduce(comm, ext, MPI.MAX)
    count, weight = ints[:n_groups], ints[n_groups:]
    extent = ext[0] + ext[1]
    empty = count == 0
    extent[empty] = (region[1] - region[0])[empty]
    axes = np.argmax(extent, axis=1).astype(np.int64)

    cuts = 0.5 * (region[0] + region[1])  # groups without particles: the region centre
    if not (~empty).any():
        return axes, cuts
    # Weighted groups with zero total weight are split by count.
    by_count = (weight == 0) | (not weighted)
    v = np.where(by_count[gs], 1, vs)
    total = np.where(by_count, count, weight)
    target = np.zeros(n_groups, dtype=np.int64)
    for gi in np.nonzero(~empty)[0]:  # loop over groups; exact Python integers
        m, n, nl = int(total[gi]), int(ranks_n[gi]), int(ranks_l[gi])
        if by_count[gi]:
            target[gi] = -((n - 2 * m * nl) // (2 * n)) + 1  # round-half-down(m*nl/n) + 1
        else:
            target[gi] = -((-m * nl) // n)  # ceil(W*nl/n)
    keys = _permute(_ordered(xs), axes[gs])
    active = ~empty
    chosen = _select(comm, keys, gs, v, target, active, n_groups)

    # Weighted: the left side is "< c" or "<= c"; take the closer to the target.
    redo = np.zeros(n_groups, dtype=bool)
    if not by_count.all():
        kc = chosen[gs]
        lt = _lex_less(keys, kc)
        le = ~_lex_less(kc, keys)
        sums = np.zeros((3, n_groups), dtype=np.int64)
        for gi in np.nonzero(~by_count & active)[0]:  # loop over groups
            rows = order[starts[gi]:starts[gi + 1]]
            sums[0, gi] = v[rows][lt[rows]].sum()
            sums[1, gi] = v[rows][le[rows]].sum()
            sums[2, gi] = le[rows].sum()
        sums = _allreduce(comm, sums, MPI.SUM)
        for gi in np.nonzero(~by_count & active)[0]:
            a, b, cle = int(sums[0, gi]), int(sums[1, gi]), int(sums[2, gi])
            w_total, n, nl = int(weight[gi]), int(ranks_n[gi]), int(ranks_l[gi])
            if 2 * w_total * nl > n * (a + b) and cle < int(count[gi]):
                redo[gi] = True
                target[gi] = cle + 1
        if redo.any():
            again = _select(comm, keys, gs, np.ones_like(v), target, redo, n_groups)
            chosen[redo] = again[redo]
    for gi in np.nonzero(active)[0]:  # back to float coordinates in axis order
        cols = (axes[gi] + np.arange(dim)) % dim
        cuts[gi, cols] = _unordered(chosen[gi])
    return axes, cuts


def imbalance(comm, n_owned: float) -> float:
    """Collective: ``max / mean`` of the owned particle counts (or work) over the ranks.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
    n_owned : int or float
        Particles owned by this rank, or their summed work (e.g. weights given to
        :meth:`RCB.build`).

    Returns
    -------
    float
        1.0 for a perfect balance (and when no rank owns anything); ``size`` when one
        rank owns everything.
    """
    n_owned = n_owned.item() if isinstance(n_owned, np.generic) else n_owned
    total = comm.allreduce(n_owned, op=MPI.SUM)
    largest = comm.allreduce(n_owned, op=MPI.MAX)
    if total == 0:
        return 1.0
    return largest * comm.size / total
