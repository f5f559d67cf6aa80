"""Injected faults, for the tests of failure handling only.

``PARSPH_FAULT`` (environment) holds comma-separated faults:

- ``nan:STEP[:RANK]``: after step STEP, the first owned particle of rank RANK (default 0)
  gets a NaN velocity (the run must stop with one clear message);
- ``checkpoint:STEP``: the checkpoint written at step STEP dies half-way (the previous
  checkpoint must survive).

Unset (always, in real runs) it costs one dictionary lookup per step.
"""
from __future__ import annotations

import os


def _parse() -> dict:
    faults = {}
    for item in filter(None, os.environ.get("PARSPH_FAULT", "").split(",")):
        kind, *args = item.split(":")
        faults[kind] = [int(a) for a in args]
    return faults


FAULTS = _parse()


def inject_nan(ctx) -> None:
    args = FAULTS.get("nan")
    if args and ctx.step == args[0] and ctx.comm.rank == (args[1] if len(args) > 1 else 0):
        if ctx.particles.n_owned:
            ctx.particles["v"][0, 0] = float("nan")


def checkpoint_fault(step: int):
    """A callable that kills the checkpoint write at ``step``, or None."""
    args = FAULTS.get("checkpoint")
    if args and step == args[0]:
        def die():
            os._exit(9)  # as abrupt as a node failure: no clean-up, no rename
        return die
    return None
