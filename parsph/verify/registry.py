"""The known answers of scenes, for ``parsph study``: each returns a relative error.

A reference is a function ``(scene, run_dir) -> float`` reading the run's output; it is
looked up by scene name, then by run mode. The physics packages register theirs with
:func:`reference` in ``parsph/verify/fluid.py`` and ``parsph/verify/solid.py``
(hydrostatic pressure, Poiseuille profiles, dam-break front, plate period, triaxial
critical state); those modules are imported only for a scene that runs their stage.

A scene without a known answer (a landslide) registers its measured quantities instead
(:func:`quantities`: ``(scene, run_dir) -> {name: value}``, the first the headline): the
study then extrapolates each to d = 0 (:func:`richardson`) and measures each run's error
against that.
"""
from __future__ import annotations

import os

import numpy as np

from parsph.errors import ParsphError

REFERENCES = {}
QUANTITIES = {}


def quantities(*names):
    """Decorator: register a function ``(scene, run_dir) -> {name: value}`` of the
    quantities a scene without a known answer is judged by (the first the headline)."""
    def wrap(fn):
        for name in names:
            QUANTITIES[name] = fn
        return fn
    return wrap


def reference(*names):
    """Decorator: register a reference function for scene names (or run modes)."""
    def wrap(fn):
        for name in names:
            REFERENCES[name] = fn
        return fn
    return wrap


def _frames(run_dir):
    from parsph.io import read_frame

    h5 = os.path.join(run_dir, "particles.h5")
    first, last = read_frame(h5, 0), read_frame(h5, "last")
    o1, o2 = np.argsort(first["id"]), np.argsort(last["id"])
    return ({k: v[o1] for k, v in first.items()}, {k: v[o2] for k, v in last.items()})


@reference("kinematic")
def kinematic_positions(scene, run_dir) -> float:
    """Kinematic mode: positions are x0 + v t exactly (wrapped on periodic axes);
    error = max deviation / particle size."""
    from parsph.io import read_frames

    first, last = _frames(run_dir)
    t = read_frames(os.path.join(run_dir, "particles.h5"))[-1][1]
    exact = first["x"] + t * first["v"]
    lo, hi = np.array(scene.domain.lo), np.array(scene.domain.hi)
    for ax, periodic in enumerate(scene.domain.periodic):
        if periodic:
            exact[:, ax] = lo[ax] + np.mod(exact[:, ax] - lo[ax], hi[ax] - lo[ax])
    return float(np.abs(last["x"] - exact).max() / scene.domain.particle_size)


#: Stage -> module that registers the references of the scenes running that stage.
PROVIDERS = {"iisph": "parsph.verify.fluid", "tlsph": "parsph.verify.solid",
             "coupled": "parsph.verify.coupling"}


def _providers(scene) -> None:
    """Import the modules that register the references of the stages the scene runs."""
    import importlib
    import importlib.util

    from parsph.step.pipeline import plan

    for stage in plan(scene):
        module = PROVIDERS.get(stage.name)
        if module and importlib.util.find_spec(module) is not None:
            importlib.import_module(module)


def reference_of(scene):
    """The reference function of a scene; a clear error if it has none."""
    _providers(scene)
    fn = REFERENCES.get(scene.name) or REFERENCES.get(scene.run.mode)
    if fn is None:
        known = ", ".join(sorted(set(REFERENCES) | set(QUANTITIES)))
        raise ParsphError(f"scene '{scene.name}' has no reference to measure errors against "
                          f"nor quantities to extrapolate; studies run on scenes with a known "
                          f"answer or registered quantities ({known})")
    return fn


def quantities_of(scene):
    """The quantities function of a scene without a known answer, or None."""
    _providers(scene)
    if REFERENCES.get(scene.name) or REFERENCES.get(scene.run.mode):
        return None
    return QUANTITIES.get(scene.name)


def richardson(sizes, values, safety: float = 1.25) -> dict:
    """Richardson extrapolation to d = 0 from the three finest sizes (any ratios).

    The observed order p solves :math:`(f_1 - f_2)/(f_2 - f_3) = (h_1^p - h_2^p)/(h_2^p -
    h_3^p)` (sizes h_1 > h_2 > h_3); then :math:`f_0 = f_3 + (f_3 - f_2) h_3^p/(h_2^p -
    h_3^p)` and its error estimate is Roache's grid convergence index of the finest run,
    ``safety`` times that correction.

    Returns
    -------
    dict
        ``order`` (NaN unless the three changes shrink monotonically), ``extrapolated``
        (NaN then), ``error_estimate`` (then the last change, a bound no better than
        that), ``finest``, ``last_change``, ``previous_change`` (the last two changes,
        signed).
    """
    h = np.asarray(sizes, float)
    f = np.asarray(values, float)
    order = np.argsort(-h)
    h, f = h[order][-3:], f[order][-3:]
    out = dict(order=float("nan"), extrapolated=float("nan"), finest=float(f[-1]),
               last_change=float(f[-1] - f[-2]) if len(f) > 1 else float("nan"),
               previous_change=float(f[-2] - f[-3]) if len(f) > 2 else float("nan"))
    out["error_estimate"] = abs(out["last_change"])
    if len(f) < 3 or not np.all(np.isfinite(f)):
        return out
    d12, d23 = f[0] - f[1], f[1] - f[2]
    if d23 == 0.0:
        out.update(order=float("inf"), extrapolated=float(f[2]), error_estimate=0.0)
        return out
    ratio = d12 / d23
    if ratio <= 1.0:  # not shrinking, or oscillating: no order to read
        return out

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - ratio

    lo, hi = 1e-3, 20.0
    if g(lo) > 0.0 or g(hi) < 0.0:
        return out
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if g(mid) < 0.0 else (lo, mid)
    p = 0.5 * (lo + hi)
    corr = (f[2] - f[1]) * h[2] ** p / (h[1] ** p - h[2] ** p)
    out.update(order=float(p), extrapolated=float(f[2] + corr),
               error_estimate=float(safety * abs(corr)))
    return out


def error_of(scene, run_dir) -> float:
    """The relative error of a finished run against its scene's reference."""
    return reference_of(scene)(scene, run_dir)
