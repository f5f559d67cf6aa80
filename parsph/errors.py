"""User-facing errors (the types live in :mod:`base.errors`, below every package; the same classes).

A :class:`ParsphError` carries a message that says what was wrong and what to do. The
CLI prints it once, on rank 0, without a traceback, and exits non-zero. Anything else
that escapes is a bug and keeps its traceback.
"""
from base.errors import NumericalError, ParsphError, Preempted, SceneError

__all__ = ["ParsphError", "SceneError", "NumericalError", "Preempted"]
