"""Global reductions over the ranks (so that physics code never calls MPI itself)."""
from __future__ import annotations

import numpy as np
from mpi4py import MPI


def global_sum(comm, value):
    """Sum of a number or of a numpy array (element-wise) over all ranks.

    Like the other reductions here it returns at once on one rank (a 2D step makes
    about thirty of them; each is an MPI call otherwise)."""
    return _allreduce(comm, value, MPI.SUM)


def global_max(comm, value):
    """Maximum of a number, or element-wise of a numpy array, over all ranks."""
    return _allreduce(comm, value, MPI.MAX)


def _allreduce(comm, value, op):
    """``op`` over all ranks of a number, or element-wise of a numpy array (a copy on one
    rank)."""
    if isinstance(value, np.ndarray):
        if comm.size == 1:
            return value.copy()
        out = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), out, op=op)
        return out
    return value if comm.size == 1 else comm.allreduce(value, op=op)


def global_min(comm, value):
    return _allreduce(comm, value, MPI.MIN)


def global_any(comm, flag: bool) -> bool:
    return bool(flag) if comm.size == 1 else bool(comm.allreduce(bool(flag), op=MPI.LOR))


def global_reduce(comm, sums=(), maxs=(), mins=()):
    """Several reductions in one collective: ``(sums, maxs, mins)``, each a tuple of
    floats, the sums, maxima and minima over the ranks of the given numbers.

    One ``Allgather`` of the numbers; every rank then reduces the gathered rows in rank
    order (the same result on every rank). A step's statistics take one call instead of
    one ``allreduce`` each."""
    if comm.size == 1:  # each number is its own reduction (float64, as gathered)
        return tuple(tuple(float(np.float64(v)) for v in part) for part in (sums, maxs, mins))
    k1, k2 = len(sums), len(sums) + len(maxs)
    mine = np.array([*sums, *maxs, *mins], dtype=np.float64)
    rows = np.empty((comm.size, mine.size))
    comm.Allgather(mine, rows)
    return (tuple(float(v) for v in rows[:, :k1].sum(axis=0)),
            tuple(float(v) for v in rows[:, k1:k2].max(axis=0, initial=-np.inf)),
            tuple(float(v) for v in rows[:, k2:].min(axis=0, initial=np.inf)))


def gather_to_root(comm, value):
    """List of every rank's value on rank 0, None elsewhere."""
    return comm.gather(value, root=0)


def broadcast(comm, value, root: int = 0):
    return comm.bcast(value, root=root)


def barrier(comm) -> None:
    comm.Barrier()


def allgather(comm, value) -> list:
    """Every rank's value, on every rank (small objects only)."""
    return comm.allgather(value)
