"""Scenes: TOML files validated into frozen dataclasses before anything is allocated.

A scene names materials, bodies (simple shapes filled with particles), walls (fixed
ghost-particle layers), loading and output. Every key can be overridden on the command
line with ``--set dotted.key=value`` (the value is read as a TOML value; list entries are
addressed as ``bodies.0.lo``). See ``docs/scenes.md`` for every key.
"""
from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field, replace
from typing import Optional
from importlib import resources

import numpy as np

from parsph.scene import schema
from parsph.errors import SceneError
from parsph.scene.materials import build_material
from parsph.scene.params_fluid import FluidNumerics
from parsph.scene.params_probes import Probe, check_probes
from parsph.scene.params_solid import Constraint, Geostatic, SolidNumerics, check_solid
from parsph.scene.schema import spec

SIDES = {2: ("left", "right", "bottom", "top"),
         3: ("left", "right", "front", "back", "bottom", "top")}


def wall_layers(scene, wall) -> int:
    """Layers of wall particles: enough to cover the kernel support 2h = 2.4 d (here, not
    in :mod:`parsph.scene.geometry`, which imports this module: a mesh's outside layers
    are checked against the domain when the scene is loaded)."""
    from parsph.core.kernel import H_OVER_D

    return wall.layers or math.ceil(2.0 * H_OVER_D - 1e-9)


@dataclass(frozen=True)
class SceneInfo:
    name: str = spec(doc="scene name")
    description: str = spec("", doc="one line shown by `parsph scenes`")


@dataclass(frozen=True)
class Domain:
    dim: int = spec(doc="2 or 3", ge=2, le=3)
    particle_size: float = spec(doc="particle spacing d (m); h = 1.2 d", gt=0.0)
    lo: tuple[float, ...] = spec(doc="lower corner of the domain (m)")
    hi: tuple[float, ...] = spec(doc="upper corner of the domain (m)")
    periodic: tuple[bool, ...] = spec((), doc="periodic axes, e.g. [true, false]")


@dataclass(frozen=True)
class Run:
    end_time: float = spec(doc="simulated end time (s): the run stops at the first sync step "
                           "at or after it (no step is shortened to land on it; "
                           "docs/reliability.md)", gt=0.0)
    mode: str = spec("physics", doc="physics | kinematic (move with initial velocity, no "
                     "forces) | geometry (build, decompose, write frame 0, stop)",
                     choices=("physics", "kinematic", "geometry"))
    dt: float = spec(0.0, doc="fixed time step (s); 0 = CFL step, eq. (49)", ge=0.0)
    cfl: float = spec(0.1, doc="CFL coefficient for moving particles, eq. (49)", gt=0.0, le=1.0)
    max_steps: int = spec(0, doc="stop after this many steps (0 = no limit)", ge=0)
    rest_fraction: float = spec(0.0, doc="stop before end_time once the kinetic energy has "
                                "stayed below this share of its peak for rest_time, after "
                                "the earthquake record's end (0 = never; docs/geostatic.md)",
                                ge=0.0, lt=1.0)
    rest_time: float = spec(2.0, doc="seconds the kinetic energy stays below rest_fraction of "
                            "its peak before the run stops at rest", gt=0.0)
    rebalance_tolerance: float = spec(1.2, doc="re-partition when max/mean owned > this", ge=1.0)
    max_particles: int = spec(200_000_000, doc="refuse scenes with more particles", gt=0)


@dataclass(frozen=True)
class Output:
    every: float = spec(doc="simulated seconds between frames, each written at the first step "
                        "at or after its time (with the time reached); the last step always "
                        "has one; output never changes the steps", gt=0.0)
    checkpoint_every: float = spec(0.0, doc="simulated seconds between checkpoints, each at the "
                                   "first sync step at or after its time (0 = at the end only)",
                                   ge=0.0)
    progress: bool = spec(True, doc="progress bar on rank 0")
    front_direction: tuple[float, ...] = spec((), doc="direction (any length) along which "
                                              "stats.csv's front (the farthest solid or fluid "
                                              "particle, m) is measured: the run-out direction; "
                                              "default +x")
    probe_every: float = spec(0.0, doc="simulated seconds between the samples of "
                              "[[probes]] (DIR/probes.csv, docs/probes.md); 0 = output.every",
                              ge=0.0)


@dataclass(frozen=True)
class Gravity:
    g: tuple[float, ...] = spec((), doc="gravity vector (m/s^2); default -9.81 on the last axis")


@dataclass(frozen=True)
class Loading:
    record: str = spec("", doc="earthquake record: CSV of time and ground accelerations "
                       "(see docs/loading.md); empty = none")
    scale: float = spec(1.0, doc="factor on the record's accelerations")
    start_time: float = spec(0.0, doc="simulated time (s) at which the record starts", ge=0.0)


@dataclass(frozen=True)
class PhaseChange:
    eps_p_limit: float = spec(0.0, doc="equivalent plastic strain eps_p past which a solid "
                              "particle becomes fluid (section 3.3); 0 = never", ge=0.0)
    fluid: str = spec("", doc="the [materials] key (a fluid model) fluidised particles take")
    min_support: float = spec(0.4, doc="a solid particle left with fewer than this share of its "
                              "initial reference neighbours (its neighbours fluidised) becomes "
                              "fluid too: a fragment too thin for TLSPH", ge=0.0, le=1.0)
    fluidise_failed: bool = spec(True, doc="a solid particle whose deformation gradient would "
                                 "invert (det F <= 0) or whose return map fails becomes fluid "
                                 "instead of stopping the run (it has failed; docs/coupling.md)")


@dataclass(frozen=True)
class Study:
    particle_sizes: tuple[float, ...] = spec((), doc="the default sweep of `parsph study` "
                                             "without --vary: particle sizes d (m), coarse to "
                                             "fine (built-in scenes: three); empty = give "
                                             "--vary", gt=0.0)


@dataclass(frozen=True)
class Body:
    name: str = spec(doc="body name")
    material: str = spec(doc="a key of [materials]")
    shape: str = spec(doc="box | polygon (2D) | extruded_polygon (3D) | heightmap (3D) | "
                      "mesh (3D, docs/geometry.md)",
                      choices=("box", "polygon", "extruded_polygon", "heightmap", "mesh"))
    lo: tuple[float, ...] = spec((), doc="box: lower corner (m)")
    hi: tuple[float, ...] = spec((), doc="box: upper corner (m)")
    vertices: tuple[tuple[float, ...], ...] = spec((), doc="polygon: [[x, y], ...] (m); "
                                                  "extruded_polygon: [[x, z], ...]")
    extent: tuple[float, ...] = spec((), doc="extruded_polygon: [y0, y1] (m)")
    top: str = spec("", doc="heightmap: grid of the top surface z(x, y): ESRI ASCII or "
                    "GeoTIFF (docs/geometry.md)")
    bottom: float = spec(-math.inf, doc="heightmap: z of the bottom (m)")
    depth: float = spec(0.0, doc="heightmap: thickness below the top surface (m), 0 = to bottom",
                        ge=0.0)
    below: float = spec(0.0, doc="heightmap: the body starts this far below the surface (m): "
                        "layers under layers (a layer = below .. below + depth)", ge=0.0)
    bottom_surface: str = spec("", doc="heightmap: grid of a base surface z_b(x, y) (ESRI ASCII "
                               "or GeoTIFF): the body lies above it (where it is at or above "
                               "the top, the body is empty); a mass of varying thickness, a "
                               "layer boundary (docs/geometry.md)")
    file: str = spec("", doc="mesh: STL (binary or ASCII) or OBJ file of a closed surface")
    scale: float = spec(1.0, doc="mesh: factor from file units to m (0.001 for mm)", gt=0.0)
    rotate: tuple[float, ...] = spec((), doc="mesh: [ax, ay, az] degrees about x, then y, "
                                     "then z, after scale")
    translate: tuple[float, ...] = spec((), doc="mesh: shift (m), after rotate")
    velocity: tuple[float, ...] = spec((), doc="initial velocity (m/s)")


@dataclass(frozen=True)
class Wall:
    name: str = spec(doc="wall name")
    shape: str = spec(doc="tank (layers around an inner box) | box (filled) | polygon (2D) | "
                      "mesh (3D: layers along a closed surface, docs/geometry.md)",
                      choices=("tank", "box", "polygon", "mesh"))
    lo: tuple[float, ...] = spec((), doc="tank: inner lower corner; box: lower corner (m)")
    hi: tuple[float, ...] = spec((), doc="tank: inner upper corner; box: upper corner (m)")
    sides: tuple[str, ...] = spec((), doc="tank: which sides have a wall (left, right, front, "
                                  "back, bottom, top)")
    vertices: tuple[tuple[float, ...], ...] = spec((), doc="polygon: [[x, y], ...] (m)")
    file: str = spec("", doc="mesh: STL (binary or ASCII) or OBJ file of a closed surface")
    scale: float = spec(1.0, doc="mesh: factor from file units to m (0.001 for mm)", gt=0.0)
    rotate: tuple[float, ...] = spec((), doc="mesh: [ax, ay, az] degrees about x, then y, "
                                     "then z, after scale")
    translate: tuple[float, ...] = spec((), doc="mesh: shift (m), after rotate")
    fill: str = spec("inside", doc="mesh: the layers lie inside the surface (the mesh is "
                     "the solid: an obstacle, a terrain block) | outside (the mesh is the flow "
                     "region, as a tank's inner box)", choices=("inside", "outside"))
    layers: int = spec(0, doc="layers of wall particles (0 = enough for the kernel support)",
                       ge=0)
    slip: str = spec("no_slip", doc="no_slip | free_slip", choices=("no_slip", "free_slip"))
    friction: Optional[float] = spec(None, doc="Coulomb friction coefficient of a TLSPH "
                                     "solid on this wall (-); default solid.wall_friction",
                                     ge=0.0)


@dataclass(frozen=True)
class Scene:
    scene: SceneInfo
    domain: Domain
    run: Run
    output: Output
    gravity: Gravity = field(default_factory=Gravity)
    loading: Loading = field(default_factory=Loading)
    solid: SolidNumerics = field(default_factory=SolidNumerics)
    geostatic: Geostatic = field(default_factory=Geostatic)
    fluid: FluidNumerics = field(default_factory=FluidNumerics)
    phase_change: PhaseChange = field(default_factory=PhaseChange)
    study: Study = field(default_factory=Study)
    bodies: tuple[Body, ...] = spec((), doc="[[bodies]] tables")
    walls: tuple[Wall, ...] = spec((), doc="[[walls]] tables")
    constraints: tuple[Constraint, ...] = spec((), doc="[[constraints]] tables (TLSPH solid)")
    probes: tuple[Probe, ...] = spec((), doc="[[probes]] tables (docs/probes.md)")
    materials: dict = field(default_factory=dict, init=False, compare=False)
    source: str = field(default="", init=False, compare=False)
    data: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    @property
    def name(self) -> str:
        return self.scene.name


# --------------------------------------------------------------------------- loading

def builtin_names() -> list[str]:
    """Names of the built-in scenes (``parsph/scenes/*.toml``)."""
    root = resources.files("parsph") / "scenes"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def builtin_path(name: str) -> str:
    return str(resources.files("parsph") / "scenes" / f"{name}.toml")


def resolve(scene: str) -> str:
    """A built-in scene name or a path to a TOML file → the file's path."""
    if os.path.isfile(scene):
        return scene
    if scene in builtin_names():
        return builtin_path(scene)
    if scene.endswith(".toml") or os.sep in scene:
        raise SceneError(f"scene file '{scene}' does not exist; give the path of a TOML scene file "
                         f"or a built-in scene name (`parsph scenes` lists them)")
    raise SceneError(f"unknown scene '{scene}'; built-in scenes: {', '.join(builtin_names())} "
                     f"(or give the path of a TOML scene file)")


def parse_value(text: str):
    """A ``--set`` value read as TOML (numbers, booleans, lists, quoted strings);
    anything else is taken as a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(raw: dict, overrides) -> dict:
    """Apply ``dotted.key=value`` strings to the raw TOML dict (in place, returned)."""
    for item in overrides or ():
        if "=" not in item:
            raise SceneError(f"--set {item!r}: expected dotted.key=value, e.g. "
                             f"--set domain.particle_size=0.01")
        key, text = item.split("=", 1)
        parts = [p for p in key.strip().split(".")]
        if not all(parts):
            raise SceneError(f"--set {item!r}: empty key part in '{key}'")
        node = raw
        for i, part in enumerate(parts[:-1]):
            where = ".".join(parts[: i + 1])
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    raise SceneError(f"--set {key}: '{where}' is not an entry of a list of "
                                     f"{len(node)} (use an index 0..{len(node) - 1})")
                node = node[int(part)]
            else:
                node = node.setdefault(part, {})
            if not isinstance(node, (dict, list)):
                raise SceneError(f"--set {key}: '{where}' is a value, not a table")
        last = parts[-1]
        value = parse_value(text.strip())
        if isinstance(node, list):
            if not last.isdigit() or int(last) >= len(node):
                raise SceneError(f"--set {key}: index '{last}' out of range")
            node[int(last)] = value
        else:
            node[last] = value
    return raw


def load_scene(scene: str, overrides=()) -> Scene:
    """Read, override and validate a scene (a built-in name or a TOML path).

    Raises
    ------
    SceneError
        For any problem, with the file and the dotted key in the message.
    """
    path = resolve(scene)
    try:
        with open(path, "rb") as fh:
            text = fh.read()
    except OSError as exc:
        raise SceneError(f"cannot read scene file '{path}': {exc.strerror}") from None
    if not text.strip():
        raise SceneError(f"scene file '{path}' is empty; a scene needs at least [scene], [domain], "
                         f"[run] and [output] tables (see `parsph scenes` for examples)")
    try:
        raw = tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise SceneError(f"scene file '{path}' is not UTF-8 text; is it really a TOML file?") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file '{path}' is not valid TOML: {exc}") from None
    file_d = raw.get("domain", {}).get("particle_size") if isinstance(raw.get("domain"), dict) \
        else None
    apply_overrides(raw, overrides)
    source = path + (" (with --set " + " ".join(overrides) + ")" if overrides else "")
    materials_raw = raw.pop("materials", {})
    for key in ("scene", "domain", "run", "output"):
        if key not in raw:
            raise SceneError(f"{source}: table [{key}] is missing; every scene has [scene], "
                             f"[domain], [run] and [output]")
    scn = schema.build(Scene, raw, "", source)
    if not isinstance(materials_raw, dict):
        raise SceneError(f"{source}: key 'materials': expected tables [materials.NAME]")
    materials = {name: build_material(name, tbl, source) for name, tbl in materials_raw.items()}
    object.__setattr__(scn, "materials", materials)
    object.__setattr__(scn, "source", os.path.abspath(path))
    scn = _normalise(scn, source)
    _regularise(scn, file_d, source)
    _cross_check(scn, source)
    check_solid(scn, source)
    check_probes(scn, source)
    object.__setattr__(scn, "data", _load_data(scn, source))
    return scn


def _normalise(scn: Scene, source: str) -> Scene:
    dim = scn.domain.dim
    dom = scn.domain
    if not dom.periodic:
        dom = replace(dom, periodic=(False,) * dim)
    g = scn.gravity
    if not g.g:
        g = Gravity(g=(0.0,) * (dim - 1) + (-9.81,))
    new = replace(scn, domain=dom, gravity=g)
    for name in ("materials", "source", "data"):
        object.__setattr__(new, name, getattr(scn, name))
    return new


def _err(source, key, message):
    raise SceneError(f"{source}: key '{key}': {message}")


def _check_vec(source, key, vec, dim, required=True):
    if not vec and not required:
        return
    if len(vec) != dim:
        _err(source, key, f"needs {dim} numbers (domain.dim = {dim}), got {len(vec)}")


def _cross_check(scn: Scene, source: str) -> None:
    dim, dom = scn.domain.dim, scn.domain
    _check_vec(source, "domain.lo", dom.lo, dim)
    _check_vec(source, "domain.hi", dom.hi, dim)
    _check_vec(source, "domain.periodic", dom.periodic, dim)
    _check_vec(source, "gravity.g", scn.gravity.g, dim)
    lo, hi = np.array(dom.lo), np.array(dom.hi)
    if np.any(hi <= lo):
        _err(source, "domain.hi", f"must be above domain.lo on every axis ({dom.lo} vs {dom.hi})")
    if np.any((hi - lo) < dom.particle_size):
        _err(source, "domain.particle_size", f"{dom.particle_size} m is larger than the domain")
    if not scn.bodies and not scn.walls:
        _err(source, "bodies", "the scene has no bodies and no walls: nothing to simulate")
    names = set()
    for i, body in enumerate(scn.bodies):
        key = f"bodies[{i}]"
        if body.name in names:
            _err(source, f"{key}.name", f"duplicate body/wall name '{body.name}'")
        names.add(body.name)
        if body.material not in scn.materials:
            known = ", ".join(sorted(scn.materials)) or "none defined"
            _err(source, f"{key}.material", f"no material '{body.material}' in [materials] "
                 f"(known: {known})")
        _check_vec(source, f"{key}.velocity", body.velocity, dim, required=False)
        _check_shape(source, key, body.shape, body, dim, lo, hi)
    _check_phase_change(scn, source)
    sizes = scn.study.particle_sizes
    if sizes and (len(sizes) < 2 or any(b >= a for a, b in zip(sizes, sizes[1:]))):
        _err(source, "study.particle_sizes", f"{list(sizes)}: give two or more sizes, coarse "
             "to fine (each smaller than the one before), e.g. [0.04, 0.02, 0.01]")
    _check_vec(source, "output.front_direction", scn.output.front_direction, dim, required=False)
    if scn.output.front_direction and not any(scn.output.front_direction):
        _err(source, "output.front_direction", "must not be the zero vector")
    for i, wall in enumerate(scn.walls):
        key = f"walls[{i}]"
        if wall.name in names:
            _err(source, f"{key}.name", f"duplicate body/wall name '{wall.name}'")
        names.add(wall.name)
        _check_shape(source, key, wall.shape, wall, dim, lo, hi)
        if wall.shape == "tank":
            if not wall.sides:
                _err(source, f"{key}.sides", f"a tank needs sides, some of {SIDES[dim]}")
            bad = [s for s in wall.sides if s not in SIDES[dim]]
            if bad:
                _err(source, f"{key}.sides", f"unknown side {bad[0]!r}; in {dim}D the sides are "
                     f"{', '.join(SIDES[dim])}")


def _regularise(scn: Scene, file_d, source: str) -> None:
    """The internal length of each softening soil (docs/regularisation.md): given, or
    :data:`~parsph.solid.regularise.DEFAULT_LENGTH_IN_D` particle sizes of the scene as
    its file gives it, so ``--set domain.particle_size`` refines with the length fixed.
    Refused, naming the key: a length on a soil that does not soften, and a length the
    particle size cannot resolve. With ``regularisation = "local"`` a given length is
    kept but unused (the paper's rule is one key away from a scene that declares one)."""
    from parsph.scene.materials import DEFAULT_LENGTH_IN_D, MIN_RESOLVED, WINDOW_IN_ELL

    d = scn.domain.particle_size
    base = file_d if isinstance(file_d, (int, float)) and file_d > 0 else d
    trigger = scn.phase_change.eps_p_limit > 0.0
    for name, mat in list(scn.materials.items()):
        if not hasattr(mat, "internal_length"):
            continue
        key = f"materials.{name}"
        needs = mat.softens() or (trigger and mat.localises())
        if mat.internal_length is not None and not needs:
            why = ("its hardening is >= 0 or its cohesion at the residual"
                   if mat.model == "drucker_prager" else
                   f"a {mat.model} soil's softening stays local")
            _err(source, f"{key}.internal_length", f"material '{name}' has no softening "
                 f"the length acts on ({why})" + (
                     "" if trigger else " and the scene has no phase change whose trigger "
                     "it would regularise") + "; remove the key")
        if mat.regularisation != "nonlocal" or not needs:
            continue
        ell = mat.internal_length
        if ell is None:
            ell = DEFAULT_LENGTH_IN_D * base
            mat = replace(mat, internal_length=ell)
            scn.materials[name] = mat
        object.__setattr__(mat, "_regularised", True)
        periods = [h - l for l, h, per in zip(scn.domain.lo, scn.domain.hi,
                                              scn.domain.periodic or ()) if per]
        window = WINDOW_IN_ELL * ell
        if trigger and periods and window >= min(periods):
            _err(source, f"{key}.internal_length", f"{ell:g} m: the phase change's window "
                 f"(radius {WINDOW_IN_ELL:g} l = {window:g} m) must be shorter than the "
                 f"periodic length {min(periods):g} m; widen the domain across its periodic "
                 f"axis or use a length below {min(periods) / WINDOW_IN_ELL:g} m")
        if ell < MIN_RESOLVED * d * (1.0 - 1e-9):
            _err(source, f"{key}.internal_length", f"{ell:g} m is below the particle size "
                 f"d = {d:g} m, which cannot resolve it (the average would not reach a "
                 f"neighbour): use d <= {ell / MIN_RESOLVED:g} m (--set "
                 f"domain.particle_size=...), or a length >= {MIN_RESOLVED * d:g} m, or "
                 f"{key}.regularisation = \"local\" for the paper's local rule")


def _check_phase_change(scn: Scene, source: str) -> None:
    """[phase_change]: a fluid material to become, and a solid to leave (section 3.3)."""
    pc = scn.phase_change
    if pc.eps_p_limit == 0.0 and not pc.fluid:
        return
    fluids = sorted(k for k, m in scn.materials.items() if "iisph" in m.stages)
    solids = [k for k, m in scn.materials.items() if "tlsph" in m.stages]
    if pc.fluid not in scn.materials:
        _err(source, "phase_change.fluid", f"names no material: '{pc.fluid}' is not a key of "
             f"[materials] (fluid materials: {', '.join(fluids) or 'none defined'})")
    if pc.fluid not in fluids:
        _err(source, "phase_change.fluid", f"material '{pc.fluid}' is not a fluid model; "
             f"name a newtonian or bingham material ({', '.join(fluids) or 'none defined'})")
    if pc.eps_p_limit > 0.0 and not solids:
        _err(source, "phase_change.eps_p_limit", "the scene has no solid (TLSPH) material "
             "whose particles could change phase")


def _check_shape(source, key, shape, item, dim, lo, hi):
    if shape in ("box", "tank"):
        _check_vec(source, f"{key}.lo", item.lo, dim)
        _check_vec(source, f"{key}.hi", item.hi, dim)
        if np.any(np.array(item.hi) <= np.array(item.lo)):
            _err(source, f"{key}.hi", f"must be above {key}.lo on every axis")
        if shape == "box" and (np.any(np.array(item.lo) < lo) or np.any(np.array(item.hi) > hi)):
            _err(source, f"{key}.lo", f"the box {item.lo}..{item.hi} is not inside the domain "
                 f"{tuple(lo)}..{tuple(hi)}; enlarge domain.lo/domain.hi")
    elif shape in ("polygon", "extruded_polygon"):
        if (shape == "polygon") != (dim == 2):
            _err(source, f"{key}.shape", f"'{shape}' is for {'2D' if shape == 'polygon' else '3D'} "
                 f"scenes (domain.dim = {dim})")
        if len(item.vertices) < 3:
            _err(source, f"{key}.vertices", "a polygon needs at least 3 vertices")
        for j, v in enumerate(item.vertices):
            if len(v) != 2:
                _err(source, f"{key}.vertices[{j}]", f"a vertex is [x, {'y' if dim == 2 else 'z'}], "
                     f"got {list(v)}")
        if shape == "extruded_polygon" and (len(item.extent) != 2 or item.extent[1] <= item.extent[0]):
            _err(source, f"{key}.extent", "needs [y0, y1] with y1 > y0")
        _check_polygon_inside(source, key, item, dim, lo, hi)
    elif shape == "mesh":
        if dim != 3:
            _err(source, f"{key}.shape", "a mesh is for 3D scenes (domain.dim = 2); draw the "
                 "section of a 2D scene as a polygon (shape = \"polygon\")")
        if not item.file:
            _err(source, f"{key}.file", "a mesh needs the path of its STL or OBJ file")
        _check_vec(source, f"{key}.rotate", item.rotate, 3, required=False)
        _check_vec(source, f"{key}.translate", item.translate, 3, required=False)
    elif shape == "heightmap":
        if dim != 3:
            _err(source, f"{key}.shape", "a heightmap body is for 3D scenes")
        if not item.top:
            _err(source, f"{key}.top", "a heightmap body needs the path of its top-surface grid")
        if not (math.isfinite(item.bottom) or item.depth > 0 or item.bottom_surface):
            _err(source, f"{key}.bottom", "a heightmap body needs 'bottom' (z of its base), "
                 "'depth' (thickness below the surface) or 'bottom_surface' (a grid of its base)")


def _check_polygon_inside(source, key, item, dim, lo, hi):
    """A polygon's vertices (and an extruded polygon's extent) inside the domain: its
    particles would otherwise start outside it, and the run stop at its first step."""
    v = np.array(item.vertices, dtype=float)
    axes = (0, 1) if dim == 2 else (0, 2)  # an extruded polygon's vertices are [x, z]
    for a, ax in enumerate(axes):
        if v[:, a].min() < lo[ax] or v[:, a].max() > hi[ax]:
            _err(source, f"{key}.vertices", f"the polygon spans {v[:, a].min():g}..{v[:, a].max():g} m "
                 f"along axis {ax}, not inside the domain's {lo[ax]:g}..{hi[ax]:g}; move the "
                 "vertices or enlarge domain.lo/domain.hi")
    if dim == 3 and (item.extent[0] < lo[1] or item.extent[1] > hi[1]):
        _err(source, f"{key}.extent", f"{list(item.extent)} is not inside the domain's "
             f"{lo[1]:g}..{hi[1]:g} along y; enlarge domain.lo/domain.hi")


def _load_data(scn: Scene, source: str) -> dict:
    """Read the data files a scene refers to (height maps), relative to the scene file."""
    from parsph.scene.heightmap import read_grid

    from parsph.scene.loading import read_record

    data = {}
    base = os.path.dirname(scn.source)
    rec = scn.loading.record
    if rec:
        path = rec if os.path.isabs(rec) else os.path.join(base, rec)
        data["record"] = read_record(path, scn.domain.dim, "loading.record", source)
    for i, body in enumerate(scn.bodies):
        if body.shape == "heightmap":
            for key in ("top", "bottom_surface"):  # the grids, by their path
                if name := getattr(body, key):
                    path = os.path.join(base, name)  # (an absolute name stays as it is)
                    data[name] = read_grid(path, key=f"bodies[{i}].{key}", source=source)
    for group, items in (("bodies", scn.bodies), ("walls", scn.walls)):
        for i, item in enumerate(items):
            if item.shape == "mesh":
                data[f"mesh:{item.name}"] = _load_mesh(scn, f"{group}[{i}]", item, base, source)
    return data


def _load_mesh(scn: Scene, key: str, item, base: str, source: str):
    """Read a mesh (rank 0), place it, and check that its particles fall in the domain."""
    from parsph.scene.mesh import read_mesh

    path = item.file if os.path.isabs(item.file) else os.path.join(base, item.file)
    mesh = read_mesh(path, f"{key}.file", source, item.scale, item.rotate, item.translate)
    grow = 0.0
    if getattr(item, "fill", "inside") == "outside":
        grow = wall_layers(scn, item) * scn.domain.particle_size
    lo, hi = mesh.lo - grow, mesh.hi + grow
    dlo, dhi = np.array(scn.domain.lo), np.array(scn.domain.hi)
    if np.any(lo < dlo) or np.any(hi > dhi):
        span = f"{np.round(lo, 6).tolist()}..{np.round(hi, 6).tolist()}"
        _err(source, f"{key}.file", f"mesh '{path}' spans {span} m after scale, rotate and "
             f"translate{' and its outside layers' if grow else ''}, not inside the domain "
             f"{list(scn.domain.lo)}..{list(scn.domain.hi)}; place it with {key}.scale, "
             f"{key}.translate or enlarge domain.lo/domain.hi")
    return mesh
