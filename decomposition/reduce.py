"""Global reductions over the ranks (so that physics code never calls MPI itself)."""
from __future__ import annotations

import numpy as np
from mpi4py import MPI


def global_sum(comm, value):
    """Sum of a number or of a numpy array (element-wise) over all ranks."""
    if isinstance(value, np.ndarray):
        out = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), out, op=MPI.SUM)
        return out
    return comm.allreduce(value, op=MPI.SUM)


def global_max(comm, value):
    return comm.allreduce(value, op=MPI.MAX)


def global_min(comm, value):
    return comm.allreduce(value, op=MPI.MIN)


def global_any(comm, flag: bool) -> bool:
    return bool(comm.allreduce(bool(flag), op=MPI.LOR))


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
