r"""Known answers of the solid scenes, for ``parsph study`` and the tests (docs/tlsph.md).

- ``elastic_plate``: period of the clamped plate (first tip zero crossing, doubled)
  against the 2D plane-strain elasticity period of the same clamped plate,
  :data:`PLATE_CONTINUUM_FACTOR` times the thin-plate (Euler–Bernoulli) period.
- ``triaxial_light``, ``triaxial_heavy``: distance of the end point of the drained path
  from the critical state line, :math:`|q - M p'| / (M p')`, from ``DIR/triaxial.csv``.
- ``newmark_block``: the permanent slip of the block (the mean displacement of its
  particles along the incline, first to last frame) against Newmark's (1965) rigid block
  under the same record (:func:`newmark_reference`, :mod:`parsph.verify.newmark`).
- ``biaxial`` has no known answer: it is judged by its peak and post-peak stress and the
  width of its shear band (:func:`biaxial_quantities`), which ``parsph study``
  extrapolates to d = 0 (docs/regularisation.md).

Each reference is ``(scene, run_dir) -> float`` (a relative error), registered with
:func:`parsph.verify.registry.reference`.
"""
from __future__ import annotations

import csv
import math
import os

import numpy as np

from parsph.errors import ParsphError
from parsph.verify.registry import quantities, reference
from parsph.solid.boundary import BETA1

#: 2D plane-strain elasticity period over the thin-plate period, for the plate of
#: Gray, Monaghan & Swift (2001): L/H = 10, nu = 0.3975, edge x = 0 fixed (every
#: displacement zero there, as the clamped particles are). Bilinear finite elements,
#: 100x10 ... 800x80 elements, Richardson-extrapolated: T = 0.25522 s against the
#: thin-plate 0.25403 s (+0.47 %). A Timoshenko beam (kappa = 5/6) gives +0.96 %: beam
#: theory's shear and root are softer than the 2D continuum fixed along x = 0.
PLATE_CONTINUUM_FACTOR = 1.0047


def thin_plate_period(E, nu, rho, H, L) -> float:
    r"""First period of a clamped-free thin plate in plane strain (Euler–Bernoulli):
    :math:`\omega = (k_1/L)^2\sqrt{E H^2 / (12\rho(1-\nu^2))}`, :math:`k_1 = 1.8751`."""
    omega = (BETA1 / L) ** 2 * math.sqrt(E * H ** 2 / (12.0 * rho * (1.0 - nu ** 2)))
    return 2.0 * math.pi / omega


def plate_reference_period(scene) -> float:
    """The reference period of an ``elastic_plate`` scene (s): 2D elasticity."""
    body = scene.bodies[0]
    mat = scene.materials[body.material]
    mode = [c for c in scene.constraints if c.profile == "cantilever_mode1"]
    if not mode:
        raise ParsphError(f"scene '{scene.name}': no cantilever_mode1 constraint")
    L = mode[0].length
    H = body.hi[1] - body.lo[1]
    if abs(L / H - 10.0) > 1e-9 or abs(mat.poisson_ratio - 0.3975) > 1e-9:
        raise ParsphError("the plate reference (2D elasticity factor) holds for L/H = 10, "
                          "nu = 0.3975 only")
    return PLATE_CONTINUUM_FACTOR * thin_plate_period(mat.young_modulus, mat.poisson_ratio,
                                                      mat.density, H, L)


def tip_period(run_dir) -> float:
    """Twice the time of the first downward zero crossing of the plate tip's transverse
    displacement (the tip particle on the mid-plane side, largest X), from particles.h5."""
    from parsph.io import read_frame, read_frames

    h5 = os.path.join(run_dir, "particles.h5")
    frames = read_frames(h5)
    first = read_frame(h5, frames[0][0])
    X = first["x"][np.argsort(first["id"])]
    tip = np.argmin(np.abs(X[:, 0] - X[:, 0].max()) + np.abs(X[:, 1]))
    prev = None
    for step, t in frames:
        fr = read_frame(h5, step)
        y = fr["x"][np.argsort(fr["id"])][tip, 1] - X[tip, 1]
        if prev is not None and prev[1] > 0 >= y:
            return 2.0 * (prev[0] + (t - prev[0]) * prev[1] / (prev[1] - y))
        prev = (t, y)
    return math.nan


@reference("elastic_plate")
def plate_period_error(scene, run_dir) -> float:
    """Relative error of the measured period against :func:`plate_reference_period`."""
    return abs(tip_period(run_dir) / plate_reference_period(scene) - 1.0)


def csl_distance(p, q, M) -> float:
    r""":math:`|q - M p'| / (M p')`: relative distance from the critical state line."""
    return abs(q - M * p) / (M * p)


def triaxial_end(run_dir) -> dict:
    """The last row of ``DIR/triaxial.csv`` (columns t, axial_strain, p, q, v, M) as floats."""
    path = os.path.join(run_dir, "triaxial.csv")
    if not os.path.exists(path):
        from parsph.solid.triaxial import write_from_stats

        path = write_from_stats(run_dir)
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ParsphError(f"{path}: no rows")
    return {k: float(v) for k, v in rows[-1].items()}


@reference("triaxial_light", "triaxial_heavy")
def triaxial_csl_error(scene, run_dir) -> float:
    """End point of the drained path against the critical state line q = M p'."""
    end = triaxial_end(run_dir)
    return csl_distance(end["p"], end["q"], end["M"])


#: The biaxial test's post-peak stress is read at this axial strain (-): about half-way
#: down its softening branch.
POST_PEAK_STRAIN = 0.015


def biaxial_curve(run_dir):
    """``(axial strain, sigma_axial)`` of a run with ``solid.triaxial_csv`` (stats.csv):
    the specimen's shortening over its height and its mean axial stress (Pa, compression
    positive)."""
    from parsph.io import read_stats

    stats = read_stats(os.path.join(run_dir, "stats.csv"))
    if "sigma_axial" not in stats:
        raise ParsphError(f"{run_dir}/stats.csv has no sigma_axial column; run the scene "
                          "with solid.triaxial_csv = true")
    return np.asarray(stats["axial_strain"]), np.asarray(stats["sigma_axial"])


def band_width(frame, d, fraction=0.5):
    r"""Width (m) of the shear band of a frame: the area of the solid particles whose
    plastic strain is at least ``fraction`` of the largest (:math:`d^2` each, 2D) over
    the band's length, its extent along the principal axis of those particles (plus d).

    Returns
    -------
    width, length : float
    """
    solid = frame["phase"] == 0
    eps, x = frame["eps_p"][solid], frame["x"][solid]
    top = eps.max()
    if not top > 0.0:
        return 0.0, 0.0
    band = x[eps >= fraction * top]
    centred = band - band.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    along = centred @ vecs[:, -1]
    length = float(along.max() - along.min() + d)
    return len(band) * d * d / length, length


@quantities("biaxial")
def biaxial_quantities(scene, run_dir) -> dict:
    """``post_peak_kpa`` (the mean axial stress at :data:`POST_PEAK_STRAIN`), ``peak_kpa``,
    ``band_width_m`` (:func:`band_width` of the last frame)."""
    from parsph.io import read_frame

    strain, sigma = biaxial_curve(run_dir)
    if strain[-1] < POST_PEAK_STRAIN:
        raise ParsphError(f"{run_dir}: the run ends at {strain[-1]:.4f} axial strain, before "
                          f"{POST_PEAK_STRAIN}; run it longer")
    last = read_frame(os.path.join(run_dir, "particles.h5"), "last")
    width, _ = band_width(last, scene.domain.particle_size)
    return {"post_peak_kpa": float(np.interp(POST_PEAK_STRAIN, strain, sigma)) / 1e3,
            "peak_kpa": float(sigma.max()) / 1e3, "band_width_m": width}


def newmark_reference(scene) -> dict:
    r"""Newmark's rigid block for a scene built like ``newmark_block``
    (:func:`parsph.verify.newmark.newmark_slip`): the incline is a level floor (normal +y)
    under gravity tilted downhill along +x, :math:`\theta = \arctan(g_x / -g_y)`; the
    floors' Coulomb coefficient :math:`\mu` (``walls.N.friction``, else
    ``solid.wall_friction``; one value for all walls); the record's x column, times
    ``loading.scale`` and shifted by ``loading.start_time``, is the ground's acceleration
    along the slope (uphill is -x). Its y column must be zero: a shaking normal to the slope
    changes the block's weight on it, which a constant :math:`a_y` leaves out.

    Returns :func:`newmark_slip`'s dict with ``a_y`` and ``theta_deg`` added."""
    from parsph.verify.newmark import newmark_slip, yield_acceleration

    g = np.asarray(scene.gravity.g, dtype=float)
    if scene.domain.dim != 2 or not (g[0] > 0.0 and g[1] < 0.0):
        raise ParsphError(f"scene '{scene.name}': the Newmark reference takes a 2D scene whose "
                          "gravity is tilted downhill along +x (g = [g sin t, -g cos t])")
    mus = {w.friction if w.friction is not None else scene.solid.wall_friction
           for w in scene.walls}
    if len(mus) != 1:
        raise ParsphError(f"scene '{scene.name}': the Newmark reference needs one friction "
                          f"coefficient on every wall, the walls have {sorted(mus)}")
    record = scene.data.get("record")
    if record is None or np.any(record.a[:, 1] != 0.0):
        raise ParsphError(f"scene '{scene.name}': the Newmark reference needs [loading] record "
                          "with a zero y column (shaking along the slope only)")
    mu = mus.pop()
    theta = math.atan2(g[0], -g[1])
    gn = float(np.linalg.norm(g))
    a_y = yield_acceleration(gn, mu, theta)
    load = scene.loading
    out = newmark_slip(record.t + load.start_time, -load.scale * record.a[:, 0], a_y,
                       a_up=gn * (mu * math.cos(theta) + math.sin(theta)))
    out.update(a_y=a_y, theta_deg=math.degrees(theta))
    return out


def block_slip(run_dir) -> float:
    """The slip (m) of a run's solid body along +x: the mean x displacement of the solid
    particles, by id, from the first frame to the last."""
    from parsph.io import read_frame

    h5 = os.path.join(run_dir, "particles.h5")
    first, last = read_frame(h5, 0), read_frame(h5, "last")
    ids = first["id"][first["phase"] == 0]
    if not len(ids):
        raise ParsphError(f"{h5}: no solid particle in the first frame")
    x0 = first["x"][np.isin(first["id"], ids)]
    x1 = last["x"][np.isin(last["id"], ids)]
    if len(x1) != len(x0):
        raise ParsphError(f"{h5}: the last frame lacks some of the first frame's solids")
    return float(x1[:, 0].mean() - x0[:, 0].mean())


@reference("newmark_block")
def newmark_slip_error(scene, run_dir) -> float:
    """Relative error of the block's slip (:func:`block_slip`) against Newmark's rigid
    block (:func:`newmark_reference`)."""
    ref = newmark_reference(scene)["slip"]
    if ref <= 0.0:
        raise ParsphError(f"scene '{scene.name}': the record never reaches the yield "
                          "acceleration; the rigid block does not slip, no relative error")
    return abs(block_slip(run_dir) / ref - 1.0)
