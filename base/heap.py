"""The heap's free pages handed back to the operating system where a step's peak is made.

glibc keeps the memory a program frees in its heap for later allocations; inside the
heap, away from its top, such free memory stays resident. A step frees and allocates
hundreds of bytes per particle (lists, work arrays, the last solve's vectors), in sizes
that change from step to step, so the free but resident part of the heap grows beside
the live data, and the peak resident size is set by it when a large allocation comes
(the PPE's hypre matrix and AMG set-up, a checkpoint). ``malloc_trim(0)`` returns every
whole free page of the heap to the system (``madvise``); a later allocation that reuses
such a page gets a fresh one from the kernel, which costs a page fault.

It lives in :mod:`base` because both :mod:`solvers` and :mod:`parsph` call it.
Callers: :mod:`solvers` around the making of a hypre matrix for a fresh AMG set-up, and
:mod:`parsph.step.run` before a checkpoint. Measured on the 3D coupled tank of
``jobs/bench_memory.py`` (docs/performance.md): peak RSS per particle 2,023 -> 1,850 bytes
at 112,761 particles on one rank. Called also before every step's lists, at the start
of the fluid step and before every solve, it saved 30 bytes more at 996,454 particles on
two ranks but made the fluid-only 3D dam break of ``jobs/bench_splishsplash.py`` 8 %
slower (the pages faulted in again each step). A call costs 0.3-2 ms there; with a small
heap it is mostly the system call's own (65 us in a 2D step of 262 particles), so it is
made only for at least :data:`MIN_ROWS` rows on the rank.
"""
from __future__ import annotations

import ctypes

__all__ = ["MIN_ROWS", "release_free_pages"]

#: Rows on this rank (particles, or a system's points) from which the heap's free pages
#: are handed back: about 30 MB of a step's transient arrays at ~1 kB per row.
MIN_ROWS = 1 << 15


def _malloc_trim():
    """glibc's ``malloc_trim`` from the process's own symbols, or None (another C library)."""
    try:
        fn = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_size_t]
    fn.restype = ctypes.c_int
    return fn


_TRIM = _malloc_trim()


def release_free_pages(rows: int) -> bool:
    """Hand the heap's whole free pages back to the system if ``rows`` (this rank's
    particles, or the rows of the system about to be solved) reach :data:`MIN_ROWS` and
    the C library can; returns whether it did. Local: no communication."""
    if _TRIM is None or rows < MIN_ROWS:
        return False
    _TRIM(0)
    return True
