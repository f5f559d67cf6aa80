"""The process's resident memory, as a user's monitor sees it (Linux ``/proc``): the whole
process, interpreter, numba, MPI, PETSc and hypre included, not only parsph's arrays.

It lives in :mod:`base` because :mod:`parsph.step.run` reports it at the end of a run (the
``done:`` line, the summary's ``peak_rss_mib``) and the benchmark jobs read it, per
particle by :func:`bytes_per_particle`."""
from __future__ import annotations

import resource
import sys


def reset_peak_rss() -> bool:
    """Reset this process's peak RSS (Linux: write ``5`` to ``/proc/self/clear_refs``, which
    sets ``VmHWM`` to the present RSS), e.g. after a warm-up in the same process. False
    where that cannot be done: :func:`peak_rss_mib` is then the process's peak since it
    started, which a job says in its output as ``peak_rss_since_start = 1``."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def bytes_per_particle(rss_mib, particles: int) -> float:
    """Bytes per particle of the ranks' memory ``rss_mib`` (MiB each, e.g. their
    :func:`peak_rss_mib`) summed over ``particles`` particles (at least one)."""
    return float(sum(rss_mib) * 2.0 ** 20 / max(int(particles), 1))


def peak_rss_mib() -> float:
    """This process's peak resident set (MiB), the whole process (interpreter, numba, PETSc,
    hypre, MPI included): ``VmHWM`` of ``/proc/self/status`` (since the last
    :func:`reset_peak_rss`), else ``ru_maxrss`` (since the process started)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    scale = 1.0 / 2 ** 20 if sys.platform == "darwin" else 1.0 / 1024.0  # bytes / KiB
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
