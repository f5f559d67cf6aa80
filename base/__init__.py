"""What every package of the house stands on: the user-facing error types and the heap's release.

``base`` imports nothing of ``decomposition``, ``solvers`` or ``parsph`` (they import
it), so ``decomposition`` can agree on an error across ranks and ``solvers`` can raise
one without reaching up into ``parsph``. ``parsph.errors`` re-exports the error types for
parsph's users.
"""
