"""User-facing errors of every package (re-exported as :mod:`parsph.errors`).

A :class:`ParsphError` carries a message that says what was wrong and what to do. The
CLI prints it once, on rank 0, without a traceback, and exits non-zero. Anything else
that escapes is a bug and keeps its traceback.
"""


class ParsphError(Exception):
    """Bad input or a run that cannot go on: the message names the key, file or value."""


class SceneError(ParsphError):
    """A scene file or ``--set`` override is invalid."""


class NumericalError(ParsphError):
    """A run stopped on a NaN/inf, a diverged solve or a particle leaving the domain."""


class Preempted(ParsphError):
    """The run was asked to stop (SIGTERM/SIGUSR1) and wrote a checkpoint to restart from."""
