"""Scene tables of the TLSPH solid: ``[solid]`` numerics, ``[geostatic]`` and ``[[constraints]]``.

Plain validated dataclasses (no physics imported): owned by the solid stage. See
``docs/tlsph.md`` for the choices behind the defaults.
"""
from __future__ import annotations

from dataclasses import dataclass

from parsph.errors import SceneError
from parsph.scene.schema import spec

#: Named initial-velocity profiles of ``[[constraints]]`` with ``kind = "initial"``.
PROFILES = ("uniform", "cantilever_mode1", "rigid_rotation")


@dataclass(frozen=True, kw_only=True)
class SolidNumerics:
    """``[solid]``: numerical parameters of the TLSPH solid (section 3)."""

    cfl: float = spec(0.5, doc="C_CFL^s of eq. (49): dt <= C d / c_p", gt=0.0, le=1.0)
    jst_eps2: float = spec(0.0, doc="JST coefficient eps(2) of eq. (9) (Laplacian term)", ge=0.0)
    jst_eps4: float = spec(1.0 / 128.0, doc="JST coefficient eps(4) of eq. (9) (bi-Laplacian "
                           "term); not given by the paper, see docs/tlsph.md", ge=0.0)
    hourglass: float = spec(0.0, doc="hourglass-control coefficient alpha of Ganzenmueller "
                            "(2015), 0 = off (elastic bodies: 1)", ge=0.0)
    correction_floor: float = spec(0.1, doc="smallest eigenvalue kept in the kernel-gradient "
                                   "correction matrix (relative to a full interior support)",
                                   gt=0.0, le=1.0)
    wall_friction: float = spec(0.0, doc="Coulomb friction coefficient solid/wall (-)", ge=0.0)
    friction_time: float = spec(0.01, doc="time (s) over which the wall friction's Coulomb "
                                "bound follows a particle's normal contact force (Prakash & "
                                "Clifton 1993); 0 = at once (docs/loading.md)", ge=0.0)
    friction_slip: float = spec(0.003, doc="slip (m) over which that bound follows the normal "
                                "force when the particle slides: it relaxes at the rate "
                                "1/friction_time + slip speed/friction_slip (the simplified "
                                "Prakash & Clifton law of Cochard & Rice 2000); inf = the time "
                                "alone (docs/loading.md)", gt=0.0, inf=True)
    max_substeps: int = spec(1, doc="coupled scenes with fluid: up to this many TLSPH sub-steps "
                             "per coupled step, which then takes the fluid's CFL step (eq. "
                             "(49)) instead of the solid's; 1 = one step for both (docs/coupling.md)",
                             ge=1, le=1000)
    ambient_pressure: float = spec(0.0, doc="uniform external pressure on every free surface "
                                   "(Pa), e.g. the cell pressure of a triaxial test", ge=0.0)
    triaxial_csv: bool = spec(False, doc="specimen averages of a triaxial test (axial strain, "
                              "p', q, v, M) in stats.csv and DIR/triaxial.csv (docs/tlsph.md)")


#: The geostatic stage's procedures (:mod:`parsph.solid.geostatic`, docs/geostatic.md).
GEOSTATIC = ("auto", "none", "k0", "gravity", "k0_gravity")


@dataclass(frozen=True, kw_only=True)
class Geostatic:
    """``[geostatic]``: the soil's initial stress before the run (docs/geostatic.md)."""

    procedure: str = spec("auto", doc="k0 (a K0 stress field from the overburden) | gravity "
                          "(gravity loading with local damping until equilibrium, from no "
                          "stress) | k0_gravity (the K0 field, then that loading) | none (no "
                          "stress, gravity acts from t = 0) | auto: k0_gravity in a scene "
                          "with an earthquake record, none otherwise", choices=GEOSTATIC)
    k0: float = spec(0.0, doc="sigma_h / sigma_v of the K0 field; 0 = each soil's own: "
                     "1 - sin(phi) (Jaky) for Drucker-Prager, nu / (1 - nu) for Hencky", ge=0.0)
    damping: float = spec(0.8, doc="local damping coefficient alpha of the gravity loading "
                          "(a force -alpha |f| sign(v) against each particle's unbalanced "
                          "force f, Cundall's; FLAC's default 0.8)", gt=0.0, lt=1.0)
    tolerance: float = spec(1e-3, doc="equilibrium: the mean unbalanced force below this share "
                            "of the weight and the kinetic energy below this share of its "
                            "peak in the stage", gt=0.0, lt=1.0)
    max_steps: int = spec(200_000, doc="the gravity loading stops the run with an error after "
                          "this many steps without equilibrium", ge=1)
    count_plastic_strain: bool = spec(False, doc="the plastic strain (and the deformation) of "
                                      "the stage count toward the phase change")


@dataclass(frozen=True, kw_only=True)
class Constraint:
    """``[[constraints]]``: Dirichlet conditions and initial velocities of solid particles.

    A constraint selects the solid particles whose *reference* position X lies in the
    box ``lo..hi``, and/or that belong to the ``bodies`` named (a body of any shape: a
    terrain-following bedrock layer no box can select). ``kind = "velocity"`` prescribes the velocity components named in
    ``axes`` at every step (``velocity = [0, 0]`` fixes them); ``kind = "initial"`` sets
    the initial velocity once from a named ``profile``.
    """

    name: str = spec(doc="constraint name")
    kind: str = spec("velocity", doc="velocity (prescribed every step) | initial (set once)",
                     choices=("velocity", "initial"))
    lo: tuple[float, ...] = spec((), doc="lower corner of the selection box in X (m); "
                                 "required without bodies")
    hi: tuple[float, ...] = spec((), doc="upper corner of the selection box in X (m); "
                                 "required without bodies")
    bodies: tuple[str, ...] = spec((), doc="select only the particles of these [[bodies]] "
                                   "(by name), in the box if one is given")
    velocity: tuple[float, ...] = spec((), doc="prescribed or uniform velocity (m/s)")
    axes: tuple[bool, ...] = spec((), doc="velocity: which components are prescribed "
                                  "(default all)")
    profile: str = spec("uniform", doc="initial: uniform | cantilever_mode1 | rigid_rotation",
                        choices=PROFILES)
    root: float = spec(0.0, doc="cantilever_mode1: x of the clamped root (m)")
    length: float = spec(1.0, doc="cantilever_mode1: free length L (m)", gt=0.0)
    tip_speed: float = spec(0.0, doc="cantilever_mode1: transverse speed at the tip (m/s)")
    centre: tuple[float, ...] = spec((), doc="rigid_rotation: centre (m)")
    omega: float = spec(0.0, doc="rigid_rotation: angular speed about the z axis (rad/s)")


def check_solid(scene, source: str) -> None:
    """Cross-check ``[solid]`` and ``[[constraints]]`` against the scene (called on load).

    Raises
    ------
    SceneError
        Naming the key, for vectors of the wrong length or empty selection boxes.
    """
    dim = scene.domain.dim
    _check_geostatic(scene, source)
    names = set()
    for i, c in enumerate(scene.constraints):
        key = f"constraints[{i}]"
        if c.name in names:
            raise SceneError(f"{source}: key '{key}.name': duplicate constraint name '{c.name}'")
        names.add(c.name)
        boxed = not c.bodies or bool(c.lo or c.hi)
        if boxed and not (c.lo or c.hi):
            raise SceneError(f"{source}: key '{key}.lo': a constraint selects the particles "
                             f"in a box (lo and hi) or of named bodies (bodies = [...]); "
                             f"give one")
        known = [b.name for b in scene.bodies]
        for name in c.bodies:
            if name not in known:
                raise SceneError(f"{source}: key '{key}.bodies': no body '{name}' in "
                                 f"[[bodies]] (bodies: {', '.join(known) or 'none'})")
        for field, vec, required in (("lo", c.lo, boxed), ("hi", c.hi, boxed),
                                     ("velocity", c.velocity, c.kind == "velocity"),
                                     ("axes", c.axes, False),
                                     ("centre", c.centre, c.profile == "rigid_rotation"
                                      and c.kind == "initial")):
            if (vec or required) and len(vec) != dim:
                raise SceneError(f"{source}: key '{key}.{field}': needs {dim} entries "
                                 f"(domain.dim = {dim}), got {len(vec)}")
        if any(h <= l for l, h in zip(c.lo, c.hi)):
            raise SceneError(f"{source}: key '{key}.hi': must be above {key}.lo on every axis")
        if c.kind == "initial" and c.profile == "uniform" and len(c.velocity) != dim:
            raise SceneError(f"{source}: key '{key}.velocity': a uniform initial profile needs "
                             f"{dim} numbers")


def geostatic_procedure(scene) -> str:
    """The scene's ``geostatic.procedure`` with ``auto`` resolved: ``k0_gravity`` where an
    earthquake record loads a solid (the quake must start from equilibrium), ``none``
    otherwise (the gravity loading is the experiment, as in the paper's section 6.2)."""
    chosen = scene.geostatic.procedure
    if chosen != "auto":
        return chosen
    solid = any("tlsph" in m.stages for m in scene.materials.values())
    return "k0_gravity" if solid and scene.loading.record and scene.run.mode == "physics" \
        else "none"


def _check_geostatic(scene, source: str) -> None:
    """``[geostatic]`` needs a solid to act on, and its K0 field a vertical gravity."""
    geo = scene.geostatic
    if geo.procedure in ("auto", "none"):
        return
    if not any("tlsph" in m.stages for m in scene.materials.values()):
        raise SceneError(f"{source}: key 'geostatic.procedure': '{geo.procedure}' needs a solid "
                         f"(TLSPH) material; this scene has none (set it to \"none\")")
    g = scene.gravity.g
    if "k0" in geo.procedure and sum(1 for c in g if c != 0.0) != 1:
        raise SceneError(f"{source}: key 'geostatic.procedure': a K0 field needs gravity along "
                         f"one axis (gravity.g = {list(g)}); use procedure = \"gravity\"")
