"""Scene tables of the probes: ``[[probes]]`` (points, lines, boxes) and their fields.

Plain validated dataclasses and name tables (no numba, no MPI): :mod:`parsph.step.probes`
samples them, :func:`check_probes` refuses a bad probe when the scene is loaded, with
the key named. See ``docs/probes.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from parsph.errors import SceneError
from parsph.scene.schema import spec

TYPES = ("point", "line", "box")
MEASURES = ("interpolate", "depth")
PHASES = ("solid", "fluid", "wall")  # index = the particle's phase code

#: Averages over the particles of a station's support (points and lines, both
#: measures): name -> what the CSV rows carry. ``v`` and ``stress`` are written per
#: component (``v_x``, ``sigma_xy``, ...).
AVERAGES = {
    "p": "pressure (Pa); a solid particle's p is its mean stress, compression positive",
    "v": "velocity components v_x, v_y(, v_z) (m/s)",
    "speed": "mean particle speed |v| (m/s)",
    "eps_p": "equivalent plastic strain (-)",
    "porosity": "porosity n (-)",
    "fluid_fraction": "volume share of fluid particles among the contributing ones (-)",
    "solid_fraction": "volume share of solid particles among the contributing ones (-)",
    "fluidised_fraction": "volume share of fluidised particles (phase change) (-)",
    "nu": "kinematic viscosity of fluid particles, 0 on others (m^2/s)",
    "stress": "Cauchy stress sigma_xx, sigma_yy, sigma_zz, sigma_xy(, sigma_xz, sigma_yz) "
              "(Pa, tension positive): tau / det F of solid particles, -p I of the others",
}
#: Kernel sums (not averages) of each measure.
SUMS = {
    "interpolate": {
        "rho": "density by summation at the point, sum_j m_j W (kg/m^3; eq. (33))",
        "volume_fraction": "sum_j V_j W: 1 inside the material, about 1/2 on its surface, "
                           "0 away from it (-)",
    },
    "depth": {
        "depth": "thickness of the material column above the station: volume per unit "
                 "horizontal area (m)",
    },
}
#: Integrals of a box over the contributing particles inside it.
BOX_FIELDS = {
    "count": "particles (-)",
    "mass": "mass (kg; kg/m in 2D)",
    "volume": "volume (m^3; m^2 in 2D)",
    "fluid_volume": "volume of fluid particles",
    "solid_volume": "volume of solid particles",
    "fluidised_volume": "volume of fluidised particles (phase change)",
    "v": "mass-weighted mean velocity v_x, v_y(, v_z) (m/s)",
    "kinetic_energy": "kinetic energy (J; J/m in 2D)",
    "p": "volume-weighted mean pressure (Pa)",
    "eps_p": "volume-weighted mean equivalent plastic strain (-)",
}
DEFAULT_FIELDS = {"interpolate": ("p", "v"), "depth": ("depth", "v")}

#: Fields only some scenes carry: name -> (what the scene needs, test on the scene).
_NEEDS = {
    "nu": ("a fluid (newtonian or bingham) material",
           lambda s: _physics(s) and any("iisph" in m.stages for m in s.materials.values())),
    "stress": ("a solid (TLSPH) material",
               lambda s: _physics(s) and any("tlsph" in m.stages for m in s.materials.values())),
    "fluidised_fraction": ("phase change ([phase_change] fluid)",
                           lambda s: _physics(s) and bool(s.phase_change.fluid)),
    "fluidised_volume": ("phase change ([phase_change] fluid)",
                         lambda s: _physics(s) and bool(s.phase_change.fluid)),
}


def _physics(scene) -> bool:
    return scene.run.mode == "physics"


@dataclass(frozen=True, kw_only=True)
class Probe:
    """``[[probes]]``: where and what to sample, written to ``DIR/probes.csv``."""

    name: str = spec(doc="probe name (the probe column of DIR/probes.csv)")
    type: str = spec(doc="point | line (`points` stations from `start` to `end`) | box "
                     "(integrals over `lo`..`hi`)", choices=TYPES)
    at: tuple[float, ...] = spec((), doc="point: position (m)")
    start: tuple[float, ...] = spec((), doc="line: first station (m)")
    end: tuple[float, ...] = spec((), doc="line: last station (m)")
    points: int = spec(0, doc="line: number of evenly spaced stations, at least 2")
    lo: tuple[float, ...] = spec((), doc="box: lower corner (m)")
    hi: tuple[float, ...] = spec((), doc="box: upper corner (m)")
    measure: str = spec("interpolate", doc="point, line: interpolate (Shepard-normalised SPH "
                        "interpolation at the station) | depth (the material column on the "
                        "vertical through the station, above it: thickness and depth "
                        "averages; docs/probes.md)", choices=MEASURES)
    fields: tuple[str, ...] = spec((), doc="what to sample (docs/probes.md); default p, v "
                                   "(depth: depth, v; box: every integral)")
    phases: tuple[str, ...] = spec(("fluid", "solid"), doc="particles that contribute: "
                                   "fluid, solid, wall")
    every: float = spec(0.0, doc="simulated seconds between samples; 0 = output.probe_every",
                        ge=0.0)


def allowed_fields(probe) -> dict:
    """Field name -> description, for this probe's type and measure."""
    if probe.type == "box":
        return BOX_FIELDS
    return {**AVERAGES, **SUMS[probe.measure]}


def fields_of(probe, scene) -> tuple[str, ...]:
    """The probe's fields (its own, or the defaults the scene carries)."""
    if probe.fields:
        return probe.fields
    if probe.type == "box":
        return tuple(f for f in BOX_FIELDS if f not in _NEEDS or _NEEDS[f][1](scene))
    return DEFAULT_FIELDS[probe.measure]


def stations(probe) -> np.ndarray:
    """(n, dim) positions of a probe's stations (m): one for a point, ``points`` for a
    line (``start`` to ``end``, evenly spaced), the centre for a box."""
    if probe.type == "point":
        return np.array([probe.at], dtype=float)
    if probe.type == "line":
        t = np.linspace(0.0, 1.0, probe.points)[:, None]
        a, b = np.array(probe.start, float), np.array(probe.end, float)
        return a + t * (b - a)
    return 0.5 * (np.array([probe.lo], float) + np.array([probe.hi], float))


def check_probes(scene, source: str) -> None:
    """Cross-check ``[[probes]]`` against the scene (called on load).

    Raises
    ------
    SceneError
        Naming the key: a duplicate name, a key of another probe type, a vector of the
        wrong length, a probe outside the domain, a line of fewer than 2 points, a box
        with lo >= hi, an unknown field or phase, a field the scene does not carry.
    """
    dim = scene.domain.dim
    lo, hi = np.array(scene.domain.lo), np.array(scene.domain.hi)
    names = set()

    def fail(key, message):
        raise SceneError(f"{source}: key '{key}': {message}")

    for i, pr in enumerate(scene.probes):
        key = f"probes[{i}]"
        if not pr.name:
            fail(f"{key}.name", "give the probe a name")
        if pr.name in names:
            fail(f"{key}.name", f"duplicate probe name '{pr.name}'")
        names.add(pr.name)
        own = {"point": ("at",), "line": ("start", "end", "points"), "box": ("lo", "hi")}
        for other in ("at", "start", "end", "points", "lo", "hi"):
            if other not in own[pr.type] and getattr(pr, other):
                users = [t for t, ks in own.items() if other in ks][0]
                fail(f"{key}.{other}", f"is a key of {users} probes, not of a {pr.type} probe")
        for name in own[pr.type]:
            if name == "points":
                continue
            vec = getattr(pr, name)
            if len(vec) != dim:
                fail(f"{key}.{name}", f"a {pr.type} probe needs {dim} numbers (domain.dim = "
                     f"{dim}), got {len(vec)}")
            if np.any(np.array(vec) < lo) or np.any(np.array(vec) > hi):
                fail(f"{key}.{name}", f"probe '{pr.name}': {list(vec)} is outside the domain "
                     f"{list(lo)}..{list(hi)}; move the probe inside or enlarge "
                     f"domain.lo/domain.hi")
        if pr.type == "line":
            if pr.points < 2:
                fail(f"{key}.points", f"a line probe needs at least 2 points (stations from "
                     f"start to end), got {pr.points}")
            if tuple(pr.start) == tuple(pr.end):
                fail(f"{key}.end", "a line probe's end must differ from its start")
        if pr.type == "box":
            if np.any(np.array(pr.hi) <= np.array(pr.lo)):
                fail(f"{key}.hi", f"must be above {key}.lo on every axis ({list(pr.lo)} vs "
                     f"{list(pr.hi)})")
            if pr.measure != "interpolate":
                fail(f"{key}.measure", "a box probe integrates over its box; measure is for "
                     "point and line probes")
        allowed = allowed_fields(pr)
        for j, f in enumerate(pr.fields):
            if f not in allowed:
                what = "box" if pr.type == "box" else f"{pr.type} probe (measure = " \
                    f"'{pr.measure}')"
                fail(f"{key}.fields[{j}]", f"unknown field '{f}' for a {what}; known: "
                     f"{', '.join(allowed)}")
            if f in _NEEDS and not _NEEDS[f][1](scene):
                fail(f"{key}.fields[{j}]", f"'{f}' needs {_NEEDS[f][0]} in run.mode = "
                     f"'physics'; this scene has none")
            if f in pr.fields[:j]:
                fail(f"{key}.fields[{j}]", f"field '{f}' is listed twice")
        if not pr.phases:
            fail(f"{key}.phases", f"name at least one of {', '.join(PHASES)}")
        for j, ph in enumerate(pr.phases):
            if ph not in PHASES:
                fail(f"{key}.phases[{j}]", f"unknown phase '{ph}'; one of {', '.join(PHASES)}")
            if ph in pr.phases[:j]:
                fail(f"{key}.phases[{j}]", f"phase '{ph}' is listed twice")
