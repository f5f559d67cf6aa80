"""Migration: send rows of named arrays to their new owner ranks.

Notes
-----
:func:`migrate` is collective. It costs one small ``Allreduce`` (agreement on the field
names, dtypes and trailing shapes, and on the validity of ``dest``), one ``Alltoall`` of
row counts, and one ``Alltoallv`` per field. Rows travel as raw bytes through a
contiguous MPI datatype of one row, so any fixed-size numpy dtype and any trailing shape
works, and counts are in rows (not bytes) so large messages do not overflow MPI's ``int``
counts as early.
"""
from __future__ import annotations

import math
import zlib

import numpy as np
from mpi4py import MPI

from decomposition.comm import raise_if_any


def row_datatype(row_bytes: int):
    """A committed MPI datatype of ``row_bytes`` contiguous bytes (free it after use).

    Parameters
    ----------
    row_bytes : int
        Size of one row in bytes (``itemsize * prod(trailing shape)``), > 0.
    """
    dtype = MPI.BYTE.Create_contiguous(int(row_bytes))
    dtype.Commit()
    return dtype


def byte_view(a: np.ndarray) -> np.ndarray:
    """The memory of a C-contiguous array as a flat ``uint8`` view (no copy)."""
    return a.reshape(-1).view(np.uint8)


def field_signature(fields: dict) -> int:
    """A 31-bit checksum of the sorted field names, dtypes and trailing shapes."""
    sig = tuple((name, np.asarray(fields[name]).dtype.str, np.asarray(fields[name]).shape[1:])
                for name in sorted(fields))
    return zlib.crc32(repr(sig).encode()) & 0x7FFFFFFF


def check_field(name: str, a: np.ndarray, where: str) -> None:
    """Raise if an array cannot travel as raw bytes (object dtype or 0-d)."""
    if a.ndim == 0:
        raise ValueError(f"{where}: field '{name}' is a scalar; pass one row per particle "
                         f"(an array of shape (N, ...))")
    if a.dtype.hasobject:
        raise TypeError(f"{where}: field '{name}' has dtype {a.dtype} which holds Python "
                        f"objects; convert it to a numeric or fixed-size string dtype")


def migrate(comm, fields: dict, dest, last=None) -> dict:
    """Collective: send row ``i`` of every field to rank ``dest[i]``.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
        The communicator (every rank calls, also those with no rows).
    fields : dict of str to ndarray
        Arrays with the same first-axis length ``N`` on this rank; any fixed-size dtype
        and trailing shape, e.g. ``(N,)``, ``(N, dim)``, ``(N, dim, dim)``. Every rank must
        pass the same names, dtypes and trailing shapes (an empty rank passes
        zero-length arrays of the right dtype and shape).
    dest : array_like of int, shape (N,)
        Destination rank of each row, in ``[0, comm.size)``.
    last : array_like of bool, shape (N,), optional
        Rows that go after all the others on their new rank (the flag travels with the
        row; on every rank alike, or nowhere). A caller that numbers some rows after
        the others (the walls of the fluid's systems) keeps its numbering in storage
        order this way, which arrivals appended after those rows would break.

    Returns
    -------
    dict of str to ndarray
        The rows this rank owns afterwards: those without ``last`` first, then those
        with it, each group ordered by source rank, then by the original local order on
        the source. On one rank, and on every rank when no row changes rank, the input
        arrays are returned unchanged (not copied); otherwise only the rows that leave
        are communicated.

    Raises
    ------
    ValueError
        On every rank, if on any rank the field lengths differ from ``len(dest)``, a
        destination is out of range, or the field names/dtypes/trailing shapes differ
        between ranks.
    """
    dest = np.asarray(dest).reshape(-1)
    size = comm.size
    n = dest.shape[0]
    problem = ""
    for name in sorted(fields):
        a = np.asarray(fields[name])
        check_field(name, a, "migrate")
        if a.shape[0] != n:
            problem = (f"field '{name}' has {a.shape[0]} rows but dest has {n}; pass one "
                       f"destination per row")
            break
    if not problem and last is not None and np.shape(last) != (n,):
        problem = f"last has shape {np.shape(last)} but dest has {n} rows; pass one flag per row"
    if not problem and n and (dest.dtype.kind not in "iu" or dest.min() < 0 or dest.max() >= size):
        problem = (f"dest must hold integer ranks in [0, {size}), got dtype {dest.dtype} and "
                   f"range [{dest.min()}, {dest.max()}]; compute it with RCB.owner")
    if size == 1:
        if problem:
            raise ValueError(f"migrate: {problem}")
        return dict(fields)

    sig = field_signature(fields)
    dest = dest.astype(np.int64, copy=False)
    stay = dest == comm.rank
    n_move = 0 if problem else n - int(stay.sum())
    flagged = int(last is not None)
    agree = np.array([sig, -sig, 1 if problem else 0, n_move, flagged, -flagged],
                     dtype=np.int64)
    comm.Allreduce(MPI.IN_PLACE, agree, op=MPI.MAX)
    if agree[2]:
        # Every rank is here: agree on the first failing rank's message.
        raise_if_any(comm, ValueError(f"migrate: {problem}") if problem else None)
    if agree[0] != -agree[1] or agree[4] != -agree[5]:
        raise ValueError("migrate: ranks passed different field names, dtypes or trailing "
                         "shapes, or last on some ranks only; pass the same set on every "
                         "rank (zero-length arrays on an empty rank)")

    if agree[3] == 0:  # no row changes rank anywhere: nothing to copy
        return dict(fields)
    # only the rows that leave travel; the staying ones are spliced in at this rank's place
    move = np.flatnonzero(~stay)
    order = move[np.argsort(dest[move], kind="stable")]
    send_counts = np.bincount(dest[move], minlength=size).astype(np.int32)
    recv_counts = np.empty(size, dtype=np.int32)
    comm.Alltoall(send_counts, recv_counts)
    send_displ = np.zeros(size, dtype=np.int32)
    recv_displ = np.zeros(size, dtype=np.int32)
    np.cumsum(send_counts[:-1], out=send_displ[1:])
    np.cumsum(recv_counts[:-1], out=recv_displ[1:])
    n_recv = int(recv_counts.sum())

    send_last = None
    if last is not None:  # where each row goes: its group, then source rank, local order
        last = np.asarray(last, dtype=np.uint8).reshape(-1)
        send_last = np.ascontiguousarray(last[order])
        recv_last = np.empty(n_recv, dtype=np.uint8)
        comm.Alltoallv([send_last, (send_counts, send_displ), MPI.UINT8_T],
                       [recv_last, (recv_counts, recv_displ), MPI.UINT8_T])
        before = int(recv_displ[comm.rank])
        flags = np.concatenate([recv_last[:before], last[stay], recv_last[before:]])
        at = np.empty(len(flags), dtype=np.int64)  # new place of each row, that order
        at[np.argsort(flags, kind="stable")] = np.arange(len(flags))
        at_stay = at[before:before + len(flags) - n_recv]
        at_recv = np.concatenate([at[:before], at[before + len(at_stay):]])
    out = {}
    for name in sorted(fields):
        a = np.asarray(fields[name])
        send = np.ascontiguousarray(a[order])
        recv = np.empty((n_recv,) + a.shape[1:], dtype=a.dtype)
        row_bytes = a.dtype.itemsize * math.prod(a.shape[1:])
        if row_bytes > 0:
            rowtype = row_datatype(row_bytes)
            try:
                comm.Alltoallv([byte_view(send), (send_counts, send_displ), rowtype],
                               [byte_view(recv), (recv_counts, recv_displ), rowtype])
            finally:
                rowtype.Free()
        before = int(recv_displ[comm.rank])  # rows from lower ranks (none from this one)
        if send_last is None:
            out[name] = np.concatenate([recv[:before], a[stay], recv[before:]])
        else:
            out[name] = np.empty((len(at),) + a.shape[1:], dtype=a.dtype)
            out[name][at_stay] = a[stay]
            out[name][at_recv] = recv
    # Keep the caller's key order.
    return {name: out[name] for name in fields}
