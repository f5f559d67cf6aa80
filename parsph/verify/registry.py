"""The known answers of scenes, for ``parsph study``: each returns a relative error.

A reference is a function ``(scene, run_dir) -> float`` reading the run's output; it is
looked up by scene name, then by run mode. The physics packages register theirs with
:func:`reference` in ``parsph/verify/fluid.py`` and ``parsph/verify/solid.py``
(hydrostatic pressure, Poiseuille profiles, dam-break front, plate period, triaxial
critical state); those modules are imported only for a scene that runs their stage.
"""
from __future__ import annotations

import os

import numpy as np

from parsph.errors import ParsphError

REFERENCES = {}


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


def reference_of(scene):
    """The reference function of a scene; a clear error if it has none."""
    import importlib
    import importlib.util

    from parsph.step.pipeline import plan

    for stage in plan(scene):
        module = PROVIDERS.get(stage.name)
        if module and importlib.util.find_spec(module) is not None:
            importlib.import_module(module)
    fn = REFERENCES.get(scene.name) or REFERENCES.get(scene.run.mode)
    if fn is None:
        known = ", ".join(sorted(REFERENCES))
        raise ParsphError(f"scene '{scene.name}' has no reference to measure errors against; "
                          f"studies run on scenes with a known answer ({known})")
    return fn


def error_of(scene, run_dir) -> float:
    """The relative error of a finished run against its scene's reference."""
    return reference_of(scene)(scene, run_dir)
