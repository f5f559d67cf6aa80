"""Halo exchange: copies of owned rows needed by other ranks (and periodic images).

Notes
-----
A :class:`Halo` is an exchange pattern: per destination rank, the list of owned rows to
send and, optionally, the offset (m) of the periodic image each row represents. It is
built once (collectively) and reused by :meth:`Halo.exchange` for any set of fields
until the particles move to other ranks.

Building
    :meth:`Halo.from_send_lists` takes any pattern. One ``Alltoall`` of the per-rank row
    counts tells every rank how many rows it will receive from whom; after that a rank
    only talks to the ranks it exchanges rows with.

    :meth:`Halo.build` derives the pattern geometrically from an :class:`RCB`: an owned
    row goes to every rank whose closed sub-box lies within ``radius`` of the row's
    position or of one of its periodic images (shifts of ``0, ±length`` per periodic
    axis). The zero-shift image is never sent to the owner itself; shifted images may
    be (a periodic axis on one rank). Rows farther than ``radius`` inside the own
    sub-box are discarded first (neither they nor their images can be near another
    sub-box, because the sub-boxes tile the global box); for each image shift only the
    ranks whose sub-box is within ``radius`` of the shifted own sub-box are tested, in
    one numba pass over the owned rows that writes the send list already grouped by
    destination (at 1.0e5 owned rows, 4.4 ms in numpy before, see docs/decomposition.md).
    Since every owned position lies in its owner's closed sub-box, the owned plus halo
    rows of a rank contain every row within ``radius`` of any of its owned rows (with
    ``radius`` < the periodic length).

Exchanging
    Each field travels as raw bytes (``MPI.BYTE``), one non-blocking message per field
    and neighbour: ``Irecv`` from every rank with rows for us, ``Isend`` to every rank
    we have rows for (tag :attr:`Tag.HALO`), the self part copied locally, then one
    ``Waitall``. Rows for one destination are ordered by local row, then image; halo
    rows arrive ordered by source rank, then by that send order. Fields named in
    ``shift_fields`` get the image offset added by the sender.

    :meth:`Halo.reverse_add` runs the same pattern backwards (tag
    :attr:`Tag.HALO_REVERSE`) and sums the returned rows per owned row.

Every rank must pass the same field names, dtypes and trailing shapes; :meth:`exchange`
and :meth:`reverse_add` are not collective (a rank with no neighbours returns at once),
but each must be called by all ranks that exchange rows with each other.
"""
from __future__ import annotations

import math

import numpy as np
from mpi4py import MPI
from numba import njit

from decomposition.comm import Tag, raise_if_any
from decomposition.exchange import byte_view, check_field


class Halo:
    """A reusable exchange pattern of owned rows to other ranks (and own images).

    Use :meth:`Halo.build` (geometric) or :meth:`Halo.from_send_lists` (any pattern).
    See the module Notes for the algorithm.

    Attributes
    ----------
    n_owned : int
        Owned rows at build time (length of the arrays :meth:`reverse_add` returns).
    n_send : int
        Rows this rank sends (a row counts once per destination and image).
    n_halo : int
        Rows this rank receives.
    send_counts, recv_counts : ndarray of int64, shape (size,)
        Rows sent to / received from each rank.
    send_index : ndarray of int64, shape (n_send,)
        Owned row of every sent row, grouped by destination rank.
    send_shift : ndarray of float64, shape (n_send, dim), or None
        Image offset (m) of every sent row; None when no row is shifted.
    """

    def __init__(self, comm, send_index, send_counts, send_shift, n_owned, recv_counts):
        self.comm = comm
        self.send_index = send_index
        self.send_counts = send_counts
        self.send_shift = send_shift
        self.n_owned = int(n_owned)
        self.recv_counts = recv_counts
        self.n_send = int(send_index.shape[0])
        self.n_halo = int(recv_counts.sum())
        self._send_displ = np.concatenate(([0], np.cumsum(send_counts)))
        self._recv_displ = np.concatenate(([0], np.cumsum(recv_counts)))
        me = comm.rank
        self._send_ranks = [r for r in np.nonzero(send_counts)[0].tolist() if r != me]
        self._recv_ranks = [r for r in np.nonzero(recv_counts)[0].tolist() if r != me]

    def without(self, keep) -> tuple["Halo", np.ndarray]:
        """Collective: this pattern with the owned rows where ``keep`` is False left out,
        and which of the halo rows stay (one exchange of the flags).

        The rows that stay keep their order on both sides: an owned row becomes row
        ``cumsum(keep) - 1``, and the halo rows that stay are the old halo's in its order,
        so fields exchanged with the new pattern equal the old exchange's rows where the
        returned flags are True. What :meth:`build` would give for the rows that stay,
        without its geometric search (a solid's reference halo after a phase change,
        :meth:`parsph.coupling.view.SolidView.without`).

        Parameters
        ----------
        keep : array_like of bool, shape (n_owned,)

        Returns
        -------
        halo : Halo
        kept : ndarray of bool, shape (n_halo,)
            Which rows of the old halo are in the new one.
        """
        keep = np.asarray(keep, dtype=bool).reshape(-1)
        if keep.shape[0] != self.n_owned:
            raise ValueError(f"Halo.without: {keep.shape[0]} flags for {self.n_owned} owned "
                             f"rows; pass one per owned row")
        size = self.comm.size
        kept = self.exchange({"keep": keep.view(np.uint8)}, shift_fields=())["keep"] != 0
        renumber = np.cumsum(keep) - 1
        sent = keep[self.send_index]
        send_counts = np.bincount(np.repeat(np.arange(size), self.send_counts)[sent],
                                  minlength=size).astype(np.int64)
        recv_counts = np.bincount(np.repeat(np.arange(size), self.recv_counts)[kept],
                                  minlength=size).astype(np.int64)
        shift = None if self.send_shift is None else self.send_shift[sent]
        return Halo(self.comm, renumber[self.send_index[sent]].astype(np.int64), send_counts,
                    shift, int(keep.sum()), recv_counts), kept

    # ------------------------------------------------------------- builders
    @classmethod
    def from_send_lists(cls, comm, send_index, send_shift=None, n_owned=None) -> "Halo":
        """Collective: a pattern from explicit per-destination lists of owned rows.

        Parameters
        ----------
        comm : mpi4py.MPI.Comm
        send_index : list of array_like of int, length ``comm.size``
            ``send_index[r]`` are the owned rows to send to rank ``r`` in send order
            (rows may repeat, e.g. for several images; ``send_index[comm.rank]`` are
            copies to self, meaningful for periodic images).
        send_shift : list of (array_like of shape (n_r, dim) or None), or None
            Image offset (m) added to ``shift_fields`` of each sent row; ``None`` (the
            list or an entry) means no shift.
        n_owned : int, optional
            Owned rows on this rank (length of :meth:`reverse_add` results). Default:
            largest sent index + 1 (0 if nothing is sent); pass it when the last owned
            rows are not sent anywhere.

        Raises
        ------
        ValueError
            On every rank, if on any rank the lists have the wrong length, an index is
            negative or not below ``n_owned``, or a shift has the wrong shape.
        """
        size = comm.size
        error, idx, shifts = None, [], []
        try:
            if len(send_index) != size:
                raise ValueError(f"Halo.from_send_lists: {len(send_index)} send lists for "
                                 f"{size} ranks; pass one (possibly empty) list per rank")
            if send_shift is not None and len(send_shift) != size:
                raise ValueError(f"Halo.from_send_lists: {len(send_shift)} shift lists for "
                                 f"{size} ranks; pass one per rank or None")
            for r in range(size):  # loop over ranks
                i = np.asarray(send_index[r]).reshape(-1)
                if i.size and i.dtype.kind not in "iu":
                    raise ValueError(f"Halo.from_send_lists: send_index[{r}] has dtype "
                                     f"{i.dtype}; pass integer row indices")
                idx.append(i.astype(np.int64))
                s = None if send_shift is None else send_shift[r]
                if s is not None:
                    s = np.asarray(s, dtype=np.float64)
                    if s.ndim != 2 or s.shape[0] != i.size:
                        raise ValueError(f"Halo.from_send_lists: send_shift[{r}] has shape "
                                         f"{s.shape}; pass ({i.size}, dim) offsets (m)")
                shifts.append(s)
            flat = np.concatenate(idx) if idx else np.zeros(0, np.int64)
            top = int(flat.max()) + 1 if flat.size else 0
            n_owned = top if n_owned is None else int(n_owned)
            if flat.size and (flat.min() < 0 or top > n_owned):
                raise ValueError(f"Halo.from_send_lists: row indices span [{flat.min()}, "
                                 f"{top - 1}] but only {n_owned} rows are owned; pass "
                                 f"indices into the owned rows and the right n_owned")
            dims = {s.shape[1] for s in shifts if s is not None}
            if len(dims) > 1:
                raise ValueError(f"Halo.from_send_lists: shifts have different widths "
                                 f"{sorted(dims)}; pass (n_r, dim) offsets with one dim")
        except ValueError as exc:
            error = exc
        raise_if_any(comm, error)

        send_counts = np.array([i.size for i in idx], dtype=np.int64)
        send_shift_all = None
        if any(s is not None for s in shifts):
            dim = next(s.shape[1] for s in shifts if s is not None)
            send_shift_all = np.concatenate(
                [np.zeros((i.size, dim)) if s is None else s for i, s in zip(idx, shifts)])
        return cls._from_flat(comm, flat, send_counts, send_shift_all, n_owned)

    @classmethod
    def _from_flat(cls, comm, flat, send_counts, send_shift, n_owned) -> "Halo":
        if comm.size == 1:  # what it sends itself is what it receives
            return cls(comm, flat, send_counts, send_shift, n_owned, send_counts.copy())
        send32 = send_counts.astype(np.int32)
        recv32 = np.empty_like(send32)
        comm.Alltoall(send32, recv32)
        return cls(comm, flat, send_counts, send_shift, n_owned, recv32.astype(np.int64))

    @classmethod
    def build(cls, comm, rcb, x_owned, radius: float, box) -> "Halo":
        """Collective: the geometric halo of an RCB partition.

        Parameters
        ----------
        comm : mpi4py.MPI.Comm
        rcb : RCB
            The partition the owned rows follow (built for ``comm.size`` ranks).
        x_owned : array_like, shape (n_owned, dim)
            Owned positions (m), wrapped into the box on periodic axes and owned per
            ``rcb.owner``.
        radius : float
            Interaction radius (m), > 0 and smaller than the box length on every
            periodic axis.
        box : Box
            The global box (its periodic flags decide which images exist).

        Returns
        -------
        Halo
            ``send_shift`` holds the image offsets when ``box`` has a periodic axis.

        Raises
        ------
        ValueError
            On every rank, if on any rank the positions have the wrong shape, or the
            radius or partition do not fit the box or communicator.
        """
        x = np.asarray(x_owned, dtype=np.float64)
        radius = float(radius)
        dim, size, me = box.dim, comm.size, comm.rank
        error = None
        if x.ndim != 2 or x.shape[1] != dim:
            error = ValueError(f"Halo.build: positions have shape {x.shape}; pass an "
                               f"(n_owned, {dim}) array (m)")
        elif not (np.isfinite(radius) and radius > 0):
            error = ValueError(f"Halo.build: radius {radius} m must be finite and positive; "
                               f"pass the kernel support radius")
        elif any(p and radius >= L for p, L in zip(box.periodic, box.length)):
            error = ValueError(f"Halo.build: radius {radius} m is not smaller than the "
                               f"periodic box length {box.length.tolist()} m; enlarge the "
                               f"periodic axes or reduce the particle spacing")
        elif rcb.n_ranks != size:
            error = ValueError(f"Halo.build: the partition has {rcb.n_ranks} ranks but the "
                               f"communicator {size}; rebuild it with RCB.build(comm, ...)")
        raise_if_any(comm, error)

        if size == 1 and not box.any_periodic:  # no other rank and no image: no halo
            empty = np.zeros(0, dtype=np.int64)
            return cls._from_flat(comm, empty, np.zeros(1, dtype=np.int64), None, x.shape[0])
        lo_all, hi_all = rcb.subboxes()
        shifts = box.image_shifts()
        rows, dest, img = _geometric_pattern(
            x, radius, lo_all[me], hi_all[me], lo_all, hi_all, np.asarray(box.lo, dtype=np.float64),
            np.asarray(box.hi, dtype=np.float64), shifts,
            *_near_ranks(lo_all, hi_all, me, radius, shifts))
        send_counts = np.bincount(dest, minlength=size).astype(np.int64)
        send_shift = shifts[img] if box.any_periodic else None
        return cls._from_flat(comm, rows, send_counts, send_shift, x.shape[0])

    # ------------------------------------------------------------ exchanges
    def _post(self, arrays: dict, out: dict, forward: bool) -> list:
        """Post the messages moving ``arrays`` into ``out`` (forward or reverse)."""
        comm, me = self.comm, self.comm.rank
        if forward:
            src_d, dst_d = self._send_displ, self._recv_displ
            to_ranks, from_ranks, tag = self._send_ranks, self._recv_ranks, int(Tag.HALO)
        else:
            src_d, dst_d = self._recv_displ, self._send_displ
            to_ranks, from_ranks, tag = self._recv_ranks, self._send_ranks, int(Tag.HALO_REVERSE)
        requests = []
        for name in sorted(arrays):  # the same order on every rank
            a, b = arrays[name], out[name]
            b[dst_d[me]:dst_d[me + 1]] = a[src_d[me]:src_d[me + 1]]
            row = a.dtype.itemsize * math.prod(a.shape[1:])
            if row == 0:
                continue
            abytes, bbytes = byte_view(a), byte_view(b)
            for r in from_ranks:
                requests.append(comm.Irecv([bbytes[dst_d[r] * row:dst_d[r + 1] * row], MPI.BYTE],
                                           source=r, tag=tag))
            for r in to_ranks:
                requests.append(comm.Isend([abytes[src_d[r] * row:src_d[r + 1] * row], MPI.BYTE],
                                           dest=r, tag=tag))
        return requests

    def exchange(self, fields: dict, shift_fields=("x",)) -> dict:
        """Send the pattern's rows of every field; return the received halo rows.

        Parameters
        ----------
        fields : dict of str to ndarray
            Arrays whose first ``n_owned`` rows are the owned rows (longer arrays, e.g.
            owned + old halo, are fine); any fixed-size dtype and trailing shape.
        shift_fields : iterable of str
            Fields (positions, shape (n, dim), m) to which the image offset of each sent
            row is added. Names not in ``fields`` are ignored.

        Returns
        -------
        dict of str to ndarray
            ``n_halo`` rows per field, ordered by source rank, then send order.
        """
        moves = self.n_send > 0 or self.n_halo > 0  # not so on one rank without images
        shift_fields = set(shift_fields)
        send, out = {}, {}
        for name in fields:
            a = np.asarray(fields[name])
            check_field(name, a, "Halo.exchange")
            if a.shape[0] < self.n_owned:
                raise ValueError(f"Halo.exchange: field '{name}' has {a.shape[0]} rows but "
                                 f"the halo was built for {self.n_owned} owned rows; rebuild "
                                 f"the halo after particles move between ranks")
            shift = name in shift_fields and self.send_shift is not None
            if shift and a.shape[1:] != self.send_shift.shape[1:]:
                raise ValueError(f"Halo.exchange: shift field '{name}' has rows of shape "
                                 f"{a.shape[1:]} but the image offsets "
                                 f"{self.send_shift.shape[1:]}; list only positions in "
                                 f"shift_fields")
            out[name] = np.empty((self.n_halo,) + a.shape[1:], dtype=a.dtype)
            if not moves:
                continue
            rows = a[self.send_index]
            if shift:
                rows = (rows + self.send_shift).astype(a.dtype, copy=False)
            send[name] = np.ascontiguousarray(rows)
        if moves:
            MPI.Request.Waitall(self._post(send, out, forward=True))
        return out

    def reverse_add(self, values: dict) -> dict:
        """Return contributions on halo rows to their owners and sum them per owned row.

        Parameters
        ----------
        values : dict of str to ndarray
            Arrays of ``n_halo`` rows (contributions accumulated on the halo rows, e.g.
            forces in N); no image offset is applied.

        Returns
        -------
        dict of str to ndarray
            Arrays of shape ``(n_owned, ...)`` (``n_owned`` at build time) with the sum
            of all contributions returned to each owned row (zeros where nothing came),
            summed in a deterministic order.
        """
        back, halo = {}, {}
        for name in values:
            a = np.asarray(values[name])
            check_field(name, a, "Halo.reverse_add")
            if a.shape[0] != self.n_halo:
                raise ValueError(f"Halo.reverse_add: field '{name}' has {a.shape[0]} rows "
                                 f"but there are {self.n_halo} halo rows; pass the halo part "
                                 f"only (rows n_owned: of the full arrays)")
            halo[name] = np.ascontiguousarray(a)
            back[name] = np.empty((self.n_send,) + a.shape[1:], dtype=a.dtype)
        MPI.Request.Waitall(self._post(halo, back, forward=False))
        out = {}
        for name, b in back.items():
            res = np.zeros((self.n_owned,) + b.shape[1:], dtype=b.dtype)
            width = math.prod(b.shape[1:])
            if b.dtype.kind == "f" and b.shape[0] and width:
                flat_b = b.reshape(b.shape[0], width)
                flat_r = res.reshape(self.n_owned, width)
                for j in range(flat_b.shape[1]):  # loop over components
                    flat_r[:, j] = np.bincount(self.send_index, weights=flat_b[:, j],
                                               minlength=self.n_owned)
            elif b.shape[0]:
                np.add.at(res, self.send_index, b)
            out[name] = res
        return out


def _near_ranks(lo_all, hi_all, me, radius, shifts):
    """Per image shift ``m``, the ranks whose sub-box overlaps rank ``me``'s sub-box
    grown by ``radius`` and shifted by ``shifts[m]`` (not ``me`` itself for the zero
    shift): ``(near_ranks, n_near)``, rank ``near_ranks[m, q]`` for ``q < n_near[m]``."""
    grown_lo, grown_hi = lo_all[me] - radius, hi_all[me] + radius
    near = np.empty((len(shifts), len(lo_all)), dtype=np.bool_)
    for m, s in enumerate(shifts):
        near[m] = ((lo_all <= grown_hi + s) & (hi_all >= grown_lo + s)).all(axis=1)
    near[0, me] = False
    n_near = near.sum(axis=1).astype(np.int64)
    near_ranks = np.zeros((len(shifts), max(1, int(n_near.max()))), dtype=np.int64)
    for m in range(len(shifts)):
        near_ranks[m, :n_near[m]] = np.flatnonzero(near[m])
    return near_ranks, n_near


@njit(cache=True, error_model="numpy")
def _gap2(y, lo, hi):
    """Squared distance (m^2) from point ``y`` to the closed box ``[lo, hi]``."""
    g2 = 0.0
    for a in range(y.shape[0]):
        g = max(0.0, lo[a] - y[a], y[a] - hi[a])
        g2 += g * g
    return g2


@njit(cache=True, error_model="numpy")
def _geometric_pattern(x, radius, my_lo, my_hi, lo_all, hi_all, glo, ghi, shifts, near_ranks,
                       n_near):
    """The send list of :meth:`Halo.build` in one pass over the owned rows (numba):
    ``(rows, dest, img)`` ordered by destination rank, then row, then image. A row
    deeper than ``radius`` inside the own sub-box is skipped; image ``m > 0`` counts only
    within ``radius`` of the global box; for image ``m`` only the ranks
    ``near_ranks[m, :n_near[m]]`` (ascending) are tested."""
    n, dim = x.shape
    n_img = shifts.shape[0]
    size = lo_all.shape[0]
    r2 = radius * radius
    y = np.empty(dim)
    counts = np.zeros(size, np.int64)
    for fill in range(2):
        if fill:
            start = np.zeros(size + 1, np.int64)
            for r in range(size):
                start[r + 1] = start[r] + counts[r]
            rows = np.empty(start[size], np.int64)
            dest = np.empty(start[size], np.int64)
            img = np.empty(start[size], np.int64)
            cursor = start[:size].copy()
        for i in range(n):
            inner = np.inf
            for a in range(dim):
                inner = min(inner, x[i, a] - my_lo[a], my_hi[a] - x[i, a])
            if inner > radius:
                continue
            for m in range(n_img):
                for a in range(dim):
                    y[a] = x[i, a] + shifts[m, a]
                if m > 0 and _gap2(y, glo, ghi) > r2:
                    continue
                for q in range(n_near[m]):
                    r = near_ranks[m, q]
                    if _gap2(y, lo_all[r], hi_all[r]) > r2:
                        continue
                    if fill:
                        k = cursor[r]
                        rows[k] = i
                        dest[k] = r
                        img[k] = m
                        cursor[r] = k + 1
                    else:
                        counts[r] += 1
    return rows, dest, img


def _box_images(box, dim):
    """Image offsets (m) of a point, zero shift first (``[0]`` without periodic axes)."""
    if box is None or not box.any_periodic:
        return np.zeros((1, dim))
    return box.image_shifts()


@njit(cache=True, error_model="numpy")
def _union(lo, hi, reach, shift):
    """Per-axis bounds of the union of the boxes ``[lo[b] - reach[b], hi[b] + reach[b]]``
    less ``shift`` (a point ``x`` with ``x + shift`` in a box lies in them)."""
    dim = lo.shape[1]
    ulo = np.full(dim, np.inf)
    uhi = np.full(dim, -np.inf)
    for b in range(lo.shape[0]):
        for a in range(dim):
            if lo[b, a] <= hi[b, a]:
                ulo[a] = min(ulo[a], lo[b, a] - reach[b] - shift[a])
                uhi[a] = max(uhi[a], hi[b, a] + reach[b] - shift[a])
    return ulo, uhi


@njit(cache=True, error_model="numpy")
def _near_boxes(x, shift, lo, hi, reach, only, flag):
    """Rows whose image ``x + shift`` lies within ``reach[b]`` of any box ``[lo[b],
    hi[b]]`` (one pass over the rows; an empty box, lo > hi on an axis, is near
    nothing); a box with ``only[b]`` is near the rows with ``flag`` set only."""
    n, dim = x.shape
    near = np.zeros(n, dtype=np.bool_)
    # the union of the widened boxes first: most rows are far from all of them (0.56
    # and 0.69 -> 0.16 and 0.24 ms per step of the 3D tank of jobs/bench_memory.py on
    # its 2 ranks)
    ulo, uhi = _union(lo, hi, reach, shift)
    for i in range(n):
        far = False
        for a in range(dim):
            if not (x[i, a] >= ulo[a] and x[i, a] <= uhi[a]):
                far = True
                break
        if far:
            continue
        for b in range(lo.shape[0]):
            if only[b] and not flag[i]:
                continue
            inside = True
            for a in range(dim):
                y = x[i, a] + shift[a]
                if not (y >= lo[b, a] - reach[b] and y <= hi[b, a] + reach[b]):
                    inside = False
                    break
            if inside:
                near[i] = True
                break
    return near


def _image_send_lists(comm, x, boxes_of, radius, shifts, with_self_zero, flag=None):
    """Per destination: the rows (and their image offsets) near any of its boxes.

    A box is ``(lo, hi)``, near the rows within ``radius`` of it, or ``(lo, hi, reach,
    only)``: near the rows within ``reach`` of it, only those with ``flag`` set if
    ``only``."""
    send, send_shift = [], []
    x = np.ascontiguousarray(x, dtype=np.float64).reshape(len(x), -1)
    flag = np.zeros(len(x), dtype=np.bool_) if flag is None else flag
    for q, boxes in enumerate(boxes_of):
        rows, offs = [], []
        boxes = [tuple(b) + (radius, False)[len(b) - 2:] for b in boxes
                 if not np.any(b[0] > b[1])]
        lo = np.array([b[0] for b in boxes], dtype=np.float64).reshape(len(boxes), x.shape[1])
        hi = np.array([b[1] for b in boxes], dtype=np.float64).reshape(len(boxes), x.shape[1])
        reach = np.array([b[2] for b in boxes], dtype=np.float64)
        only = np.array([b[3] for b in boxes], dtype=np.bool_)
        for k, s in enumerate(shifts):
            if k == 0 and q == comm.rank and not with_self_zero:
                continue
            idx = np.flatnonzero(_near_boxes(x, np.asarray(s, dtype=np.float64), lo, hi,
                                             reach, only, flag))
            rows.append(idx)
            offs.append(np.repeat(s[None, :], len(idx), axis=0))
        send.append(np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64))
        send_shift.append(np.concatenate(offs) if offs else np.zeros((0, x.shape[-1])))
    return send, send_shift


def proximity_halo(comm, x_owned, select, radius: float, lo, hi, box=None) -> Halo:
    """Collective: send the selected owned rows to every rank whose box is within reach.

    Parameters
    ----------
    x_owned : ndarray (n_owned, dim)
        Current positions of the owned rows (m).
    select : ndarray of bool (n_owned,)
        Rows that may be sent (e.g. wall particles).
    radius : float
        Reach (m): a row goes to rank ``q`` if it lies within ``radius`` of ``q``'s box.
    lo, hi : ndarray (dim,)
        This rank's box (e.g. the bounding box of the particles it needs neighbours
        for); an empty box (lo > hi) receives nothing.

    Notes
    -----
    Unlike :meth:`Halo.build`, the boxes need not come from a partition: each rank
    announces the box it needs data around (one ``allgather``), so this serves
    neighbourhoods in the current configuration when ownership follows another one
    (TLSPH particles are owned by their reference position). Rows are also sent to
    this rank itself when they lie near its box, so the result is the complete set of
    selected rows near the box. With a periodic ``box`` the periodic images of the rows
    are sent too (their ``x`` shifted by the exchange).
    """
    x = np.asarray(x_owned, dtype=float)
    rows = np.flatnonzero(np.asarray(select, dtype=bool))
    periodic = box is not None and box.any_periodic
    boxes = comm.allgather((np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)))
    send, shift = _image_send_lists(comm, x[rows], [[b] for b in boxes], radius,
                                    _box_images(box, x.shape[-1]), True)
    return Halo.from_send_lists(comm, [rows[i] for i in send], shift if periodic else None,
                                n_owned=len(x))
