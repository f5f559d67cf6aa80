"""The communicator, MPI tags, and collective error agreement.

Notes
-----
An error raised on one rank only must not leave the other ranks waiting in a
collective. Every stage that can fail on input (scene validation, file reads, numerical
checks) runs inside :func:`collective`, which turns a local exception into the same
exception on every rank: the ranks agree on the first failing rank's message through
one ``allgather`` and all raise it together.
"""
from __future__ import annotations

import enum
from contextlib import contextmanager

from mpi4py import MPI

import base.errors as errors
from base.errors import ParsphError


class Tag(enum.IntEnum):
    """Every point-to-point tag parsph uses (no tags hashed from names)."""

    MIGRATE = 101
    HALO = 102
    HALO_REVERSE = 103


def world():
    """The communicator parsph runs on (``MPI.COMM_WORLD``)."""
    return MPI.COMM_WORLD


def raise_if_any(comm, exc: BaseException | None) -> None:
    """Collective: if ``exc`` is not None on any rank, raise on every rank.

    The exception raised everywhere is the one of the lowest failing rank, with its
    type and message (types other than parsph's own become ``RuntimeError``).
    """
    if comm.size == 1:  # nothing to agree on (a step checks several times)
        if exc is not None:
            raise exc
        return
    payload = None if exc is None else (type(exc).__name__, str(exc), isinstance(exc, ParsphError))
    gathered = comm.allgather(payload)
    for rank, item in enumerate(gathered):
        if item is None:
            continue
        if exc is not None and rank == comm.rank:
            raise exc
        name, message, is_parsph = item
        if is_parsph:
            cls = getattr(errors, name, ParsphError)
            raise cls(message)
        raise RuntimeError(f"rank {rank} failed: {name}: {message}")


@contextmanager
def collective(comm):
    """Context manager: an exception inside the block is raised on every rank.

    Every rank must enter and leave the block (it ends with one ``allgather``).
    """
    error = None
    try:
        yield
    except Exception as exc:  # noqa: BLE001 - re-raised on every rank below
        error = exc
    raise_if_any(comm, error)


_NODE_COMMS = {}


def node_comm(comm):
    """The ranks of ``comm`` that share this node's memory (cached per communicator)."""
    key = comm.py2f()
    if key not in _NODE_COMMS:
        _NODE_COMMS[key] = comm.Split_type(MPI.COMM_TYPE_SHARED)
    return _NODE_COMMS[key]


def abort(comm, code: int) -> None:
    """Take every rank down (after an unexpected error on this one); no-op on one rank."""
    if comm.size > 1:
        comm.Abort(code)


def on_root(comm, fn, *args):
    """Collective: ``fn(*args)`` on rank 0 only; every rank gets its result or its error.

    For work that must happen once (reading and checking an input file): a
    :class:`~base.errors.ParsphError` raised on rank 0 is raised on every rank with
    the same message, so one message is printed and no rank waits.
    """
    payload = None
    if comm.rank == 0:
        try:
            payload = ("ok", fn(*args))
        except ParsphError as exc:
            payload = ("error", (type(exc).__name__, str(exc)))
    status, value = comm.bcast(payload, root=0)
    if status == "error":
        raise getattr(errors, value[0], ParsphError)(value[1])
    return value
