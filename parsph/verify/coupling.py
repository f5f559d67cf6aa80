r"""Known answers of the coupled scenes, for ``parsph study`` and the tests (docs/coupling.md).

- ``elastic_gate``: the free-end displacement of the rubber gate of Antoci, Gallati &
  Sibilla (2007) against their measurement (``parsph/scenes/data/antoci_2007_gate_*.csv``):
  the mean absolute difference of the horizontal and vertical displacements over the
  measured points, relative to the largest measured horizontal displacement.

Each reference is ``(scene, run_dir) -> float`` (a relative error), registered with
:func:`parsph.verify.registry.reference`.
"""
from __future__ import annotations

import os

import numpy as np

from parsph.errors import ParsphError
from parsph.verify.registry import reference

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "scenes", "data")


def measured_gate(axis: str):
    """``(t, u)``: the measured free-end displacement (s, m) of Antoci et al. (2007),
    ``axis`` ``"x"`` (horizontal, in the flow direction) or ``"y"`` (vertical, upward)."""
    t, u = np.loadtxt(os.path.join(DATA, f"antoci_2007_gate_d{axis}.csv"), delimiter=",",
                      skiprows=1, unpack=True)
    return t, u


def free_end(run_dir):
    """``(t, dx, dy)``: time (s) and displacement (m) of the gate's free end, the mean of
    the solid particles of its lowest layer at t = 0, from every frame of ``particles.h5``
    that holds all of them (a particle that fluidised ends the series)."""
    from parsph.io import read_frame, read_frames

    h5 = os.path.join(run_dir, "particles.h5")
    frames = read_frames(h5)
    first = read_frame(h5, frames[0][0])
    solid = first["phase"] == 0
    if not solid.any():
        raise ParsphError(f"{h5}: no solid particle in the first frame: not a gate")
    y = first["x"][solid][:, 1]
    ids = np.sort(first["id"][solid][y < y.min() + 1e-9 * max(abs(y.min()), 1.0)])
    start = None
    out = []
    for step, t in frames:
        f = read_frame(h5, step)
        pos = np.searchsorted(np.sort(f["id"]), ids)
        order = np.argsort(f["id"])
        if pos.max(initial=-1) >= len(order) or not np.array_equal(f["id"][order[pos]], ids):
            break
        x = f["x"][order[pos]].mean(axis=0)
        start = x if start is None else start
        out.append((t, x[0] - start[0], x[1] - start[1]))
    return tuple(np.array(col) for col in zip(*out))


def gate_errors(run_dir):
    """``(dx error, dy error)``: mean absolute difference of simulated and measured
    free-end displacement over the measured points within the run (m), each axis."""
    t, dx, dy = free_end(run_dir)
    errs = []
    for axis, sim in (("x", dx), ("y", dy)):
        te, ue = measured_gate(axis)
        keep = te <= t[-1] + 1e-12
        if keep.sum() < 2:
            raise ParsphError(f"{run_dir}: the run ends at t = {t[-1]:.3g} s, before the "
                              "measured gate displacement; run to 0.4 s")
        errs.append(float(np.mean(np.abs(np.interp(te[keep], t, sim) - ue[keep]))))
    return tuple(errs)


@reference("elastic_gate")
def elastic_gate(scene, run_dir) -> float:
    """Mean absolute free-end displacement error (both axes) over the largest measured
    horizontal displacement (46 mm)."""
    ex, ey = gate_errors(run_dir)
    return 0.5 * (ex + ey) / float(np.abs(measured_gate("x")[1]).max())
