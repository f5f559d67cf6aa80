r"""Known answers of the coupled scenes, for ``parsph study`` and the tests (docs/coupling.md).

- ``elastic_gate``: the free-end displacement of the rubber gate of Antoci, Gallati &
  Sibilla (2007) against their measurement (``parsph/scenes/data/antoci_2007_gate_*.csv``):
  the mean absolute difference of the horizontal and vertical displacements over the
  measured points, relative to the largest measured horizontal displacement.

Each reference is ``(scene, run_dir) -> float`` (a relative error), registered with
:func:`parsph.verify.registry.reference`.

The landslides (``slope_failure``, ``slope_failure_3d``) have no known answer: they are
judged by their run-out, fluidised volume and time to rest (:func:`landslide`), which
``parsph study`` extrapolates to d = 0.
"""
from __future__ import annotations

import os

import numpy as np

from parsph.errors import ParsphError
from parsph.verify.registry import quantities, reference

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


#: The run-out is where this fraction of the moving mass stays behind (docs/slope.md: the
#: farthest particle is one loose grain that round-off alone moved by 0.48 m).
RUNOUT_FRACTION = 0.99
#: At rest: the kinetic energy stays below this fraction of its peak.
REST_FRACTION = 1e-2


def run_out(scene, frame) -> float:
    """Distance (m) along ``output.front_direction`` that :data:`RUNOUT_FRACTION` of the
    soil's mass (solid and fluidised, no walls) stays behind, from the origin."""
    direction = np.asarray(scene.output.front_direction, float)
    if not direction.size:
        raise ParsphError(f"scene '{scene.name}' declares no output.front_direction: no "
                          "run-out to measure")
    return run_out_along(frame, direction)


def run_out_along(frame, direction) -> float:
    """Distance (m) along ``direction`` (any length) that :data:`RUNOUT_FRACTION` of the
    mass of a frame's non-wall particles stays behind, from the origin: the position of
    the particle at which the cumulative mass, in order along ``direction``, reaches
    that fraction (equal masses where the frame has none)."""
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    moving = frame["phase"] != 2
    along = frame["x"][moving] @ direction
    mass = frame["m"][moving] if "m" in frame else np.ones(len(along))
    order = np.argsort(along)
    cum = np.cumsum(mass[order])
    return float(along[order][np.searchsorted(cum, RUNOUT_FRACTION * cum[-1])])


def time_to_rest(stats) -> float:
    """The last time (s) the kinetic energy is at or above :data:`REST_FRACTION` of its
    peak (the end of the run if it is then)."""
    t, ke = np.asarray(stats["time"], float), np.asarray(stats["kinetic_energy"], float)
    peak = ke.max() if len(ke) else 0.0
    if peak <= 0.0:
        return 0.0
    return float(t[np.flatnonzero(ke >= REST_FRACTION * peak)[-1]])


@quantities("slope_failure", "slope_failure_3d")
def landslide(scene, run_dir) -> dict:
    """``runout_m`` (:func:`run_out` of the last frame), ``fluidised`` (m^2 per metre in
    2D, m^3 in 3D: stats.csv's ``fluidised_volume``), ``time_to_rest_s``
    (:func:`time_to_rest`); in 3D with periodic axes also ``fluidised_per_width_m2``, the
    fluidised volume per metre of the periodic width (comparable with the 2D section)."""
    from parsph.io import read_frame, read_stats

    stats = read_stats(os.path.join(run_dir, "stats.csv"))
    last = read_frame(os.path.join(run_dir, "particles.h5"), "last")
    out = {"runout_m": run_out(scene, last),
           "fluidised": float(stats["fluidised_volume"][-1]),
           "time_to_rest_s": time_to_rest(stats)}
    dom = scene.domain
    width = [h - l for l, h, p in zip(dom.lo, dom.hi, dom.periodic) if p]
    if dom.dim == 3 and width:
        out["fluidised_per_width_m2"] = out["fluidised"] / float(np.prod(width))
    return out
