"""Solver failures, agreed on by every rank: one rank's error is raised on all of them."""
from __future__ import annotations

from base.errors import NumericalError


class SolverError(NumericalError):
    """A linear solve did not converge; the message names the system, reason and what to try."""


def agree(comm, error: tuple[type, str] | None, flag: int = 0) -> int:
    """Collective: raise one rank's error on every rank, else return the bitwise OR of
    the ranks' ``flag`` (a bool is the one-bit case: ``any(flag)``).

    ``error`` is ``(exception type, message)`` or None. The error raised everywhere is
    the lowest failing rank's, with the same type, so that no rank is left waiting in a
    later collective while another one has given up.
    """
    item = None if error is None else (error[0].__name__, error[1])
    gathered = [(item, int(flag))] if comm.size == 1 else comm.allgather((item, int(flag)))
    for rank, (item, _) in enumerate(gathered):
        if item is not None:
            name, message = item
            cls = SolverError if name == SolverError.__name__ else ValueError
            raise cls(f"rank {rank}: {message}")
    out = 0
    for _, bits in gathered:
        out |= bits
    return out
