"""Known answers of the fluid scenes, for ``parsph study`` and the fluid tests.

Each registered function is ``(scene, run_dir) -> float``, a relative error of the run
in ``run_dir``; the formulas below (exact profiles, front position, experiment data)
are the ones the tests use, imported from here.
"""
from __future__ import annotations

import math
import os

import numpy as np

from parsph.verify.registry import reference

#: Digitised experiments of the dam break (z/a against T = t sqrt(2 g / a)); sources in
#: parsph/scenes/data/README.md.
DATA = os.path.join(os.path.dirname(__file__), "..", "scenes", "data")
DAM_BREAK_DATA = ("martin_moyce_1952.csv", "koshizuka_oka_1996.csv")


def last_frame(run_dir):
    from parsph.io import read_frame

    return read_frame(os.path.join(run_dir, "particles.h5"), "last")


def _fluid(f):
    return f["phase"] == 1


def hydrostatic_error(f, rho, g, H):
    """Per fluid particle |p - rho g (H - y)| / (rho g H) of a frame."""
    fl = _fluid(f)
    y, p = f["x"][fl, 1], f["p"][fl]
    return np.abs(p - rho * g * (H - y)) / (rho * g * H)


def poiseuille_exact(y, F, nu, width=1.0):
    """Velocity of the plane Poiseuille flow driven by the body force F (walls y = 0, width)."""
    return F * y * (width - y) / (2 * nu)


def bingham_poiseuille_exact(y, F, nu, tau_y, rho=1.0, width=1.0):
    """Bingham channel: plug |y - width/2| < tau_y / (rho F), parabolic outside."""
    yp = tau_y / (rho * F)
    half = 0.5 * width
    yc = np.abs(y - half)
    return np.where(yc < yp, F * (half - yp) ** 2 / (2 * nu),
                    F / (2 * nu) * ((half - yp) ** 2 - (yc - yp) ** 2))


def channel_profile(f, exact):
    """(u, exact(y)) of the fluid particles of a frame."""
    fl = _fluid(f)
    return f["v"][fl, 0], exact(f["x"][fl, 1])


def profile_l2(u, ex):
    """L2 error of a velocity profile relative to its largest exact value."""
    return float(np.sqrt(np.mean((u - ex) ** 2)) / np.abs(ex).max())


def front_positions(out, a, d, g=9.81):
    """(T, Z): t sqrt(2 g / a) and the front x / a (rightmost fluid particle near the floor)."""
    from parsph.io import read_frame, read_frames

    h5 = os.path.join(out, "particles.h5")
    T, Z = [], []
    for step, t in read_frames(h5):
        f = read_frame(h5, step)
        x = f["x"][f["phase"] == 1]
        low = x[:, 1] < 0.1 * a + 1e-9
        T.append(t * math.sqrt(2 * g / a))
        Z.append((x[low, 0].max() + 0.5 * d) / a)
    return np.array(T), np.array(Z)


def experiment(fname):
    """(T, Z) of a digitised experiment in parsph/scenes/data."""
    return np.loadtxt(os.path.join(DATA, fname), delimiter=",", comments="#", unpack=True)


def front_errors(T, Z, fname, t_min=0.5):
    """(Te, simulated Z, experimental Z) at the experiment's times in (t_min, T.max()]."""
    Te, Ze = experiment(fname)
    keep = (Te > t_min) & (Te <= T.max())
    return Te[keep], np.interp(Te[keep], T, Z), Ze[keep]


def _water(scene):
    body = scene.bodies[0]
    mat = scene.materials[body.material]
    return body, mat, float(np.linalg.norm(scene.gravity.g))


@reference("hydrostatic")
def hydrostatic(scene, run_dir) -> float:
    """rms over the fluid particles of |p - rho g (H - y)| / (rho g H), last frame."""
    body, mat, g = _water(scene)
    err = hydrostatic_error(last_frame(run_dir), mat.density, g, body.hi[1] - body.lo[1])
    return float(np.sqrt(np.mean(err ** 2)))


@reference("poiseuille", "bingham_poiseuille")
def channel(scene, run_dir) -> float:
    """L2 error of the last frame's velocity profile against the exact (steady) one."""
    body, mat, _ = _water(scene)
    F = float(scene.gravity.g[0])
    width = body.hi[1] - body.lo[1]
    if scene.name == "poiseuille":
        def exact(y):
            return poiseuille_exact(y - body.lo[1], F, mat.viscosity, width)
    else:
        def exact(y):
            return bingham_poiseuille_exact(y - body.lo[1], F, mat.viscosity, mat.cohesion,
                                            mat.density, width)
    return profile_l2(*channel_profile(last_frame(run_dir), exact))


@reference("dam_break")
def dam_break(scene, run_dir) -> float:
    """Mean relative error of the front z/a against both experiments at their times
    within the run (T > 0.5)."""
    body, _, g = _water(scene)
    a = body.hi[0] - body.lo[0]
    T, Z = front_positions(run_dir, a, scene.domain.particle_size, g)
    errs = []
    for fname in DAM_BREAK_DATA:
        _, sim, ze = front_errors(T, Z, fname)
        errs.extend(np.abs(sim - ze) / ze)
    return float(np.mean(errs)) if errs else float("nan")
