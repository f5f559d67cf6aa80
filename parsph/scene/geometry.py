"""Particles from a scene's bodies and walls, generated in parallel.

Notes
-----
No rank builds the whole set. Each body or wall is a regular lattice of spacing ``d``
over its bounding box (points at ``origin + (k + 1/2) d``) filtered by an inside test.
Rank ``r`` of ``P`` generates the lattice indices ``[r T / P, (r + 1) T / P)`` of the
``T`` candidates, keeps those inside, and numbers them with an exclusive prefix sum of
the kept counts. Global ids therefore follow lattice order and do not depend on the
rank count, which is what the 1-rank vs 2-rank comparisons by id rely on. Particles are
then moved to their owners by recursive coordinate bisection (see :mod:`parsph.domain`).
"""
from __future__ import annotations

import math

import numpy as np

from decomposition.comm import raise_if_any
from decomposition.numbering import global_offset
from parsph.errors import SceneError
from parsph.scene.heightmap import surface
from parsph.core.kernel import H_OVER_D
from parsph.scene.materials import PHASE_WALL
from parsph.scene.loader import SIDES, Scene, wall_layers

_CHUNK = 1 << 22  # candidates handled at once per rank (bounds temporary memory)


def _points_in_polygon(px, py, verts) -> np.ndarray:
    """Even-odd rule, vectorised over points (loop over the few edges)."""
    inside = np.zeros(px.shape, dtype=bool)
    vx, vy = verts[:, 0], verts[:, 1]
    n = len(verts)
    for k in range(n):
        x1, y1, x2, y2 = vx[k], vy[k], vx[(k + 1) % n], vy[(k + 1) % n]
        crosses = (y1 > py) != (y2 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (px < xc)
    return inside


def _counts(lo, hi, d):
    return np.maximum(np.floor((np.asarray(hi) - np.asarray(lo)) / d + 1e-9).astype(np.int64), 0)


#: Lattices with at most this many candidates are counted exactly by :meth:`_Lattice.kept`;
#: larger ones by a sample of this many candidates.
_COUNT_EXACT = 1 << 21


class _Lattice:
    """A lattice (origin, counts) and an inside test for one body or wall.

    ``exact_count`` (optional) returns the number of candidates inside without testing
    them (a tank: closed form); otherwise :meth:`kept` tests them, or a sample of them.
    """

    def __init__(self, origin, counts, inside, exact_count=None):
        self.origin = np.asarray(origin, dtype=float)
        self.counts = np.asarray(counts, dtype=np.int64)
        self.inside = inside
        self._exact_count = exact_count

    @property
    def total(self) -> int:
        """Candidates: every lattice point of the bounding box."""
        return int(np.prod(self.counts)) if len(self.counts) else 0

    def points(self, idx, d):
        """Positions (m) of the lattice candidates with flat indices ``idx``."""
        return self.origin + (np.stack(np.unravel_index(idx, tuple(self.counts)), axis=1) + 0.5) * d

    def kept(self, d: float) -> int:
        """Particles this lattice generates, without generating them (one rank, no MPI).

        Exact for unfiltered boxes and tanks, and for filtered lattices of at most
        ``_COUNT_EXACT`` candidates. Larger filtered lattices (polygons, heightmaps at
        fine particle sizes) are sampled: the kept fraction of ``_COUNT_EXACT`` random
        candidates (fixed seed) times the total, plus four standard deviations of that
        estimate, so that it is an upper bound in all but a 3e-5 tail.
        """
        total = self.total
        if self.inside is None or total == 0:
            return total
        if self._exact_count is not None:
            return int(self._exact_count())
        if total <= _COUNT_EXACT:
            return sum(int(self.inside(self.points(np.arange(a, min(a + _CHUNK, total)), d)).sum())
                       for a in range(0, total, _CHUNK))
        idx = np.random.default_rng(12345).integers(0, total, size=_COUNT_EXACT)
        frac = float(self.inside(self.points(idx, d)).mean())
        sigma = math.sqrt(max(frac * (1.0 - frac), 1.0 / _COUNT_EXACT) / _COUNT_EXACT)
        return min(total, int(math.ceil((frac + 4.0 * sigma) * total)))


def _nearest_body_origin(scene: Scene, lo, hi):
    """The lattice origin of the body nearest the box [lo, hi] within the kernel support
    plus d, or None (no body that close)."""
    d = scene.domain.particle_size
    reach = 2.0 * H_OVER_D * d + d
    best, origin = math.inf, None
    for body in scene.bodies:
        lat = _lattice(scene, body, False)
        blo, bhi = lat.origin, lat.origin + lat.counts * d
        gap = np.maximum(0.0, np.maximum(blo - hi, lo - bhi))
        dist = float(np.sqrt((gap * gap).sum()))
        if dist <= reach and dist < best:
            best, origin = dist, lat.origin
    return origin


def _wall_box_lattice(scene: Scene, item) -> _Lattice:
    """A box wall's lattice. Next to a body it continues that body's lattice: the centres
    ``body origin + (k + 1/2) d`` that lie in [lo, hi], so the wall's first layer is d
    from the body's last whatever the box's thickness (a 0.15 m floor at d = 0.035 m put
    its top layer 1.29 d under the soil, and the soil dropped onto it: the slope's sliding
    area doubled, docs/geometry.md). Elsewhere: from lo, as a body."""
    d = scene.domain.particle_size
    lo, hi = np.asarray(item.lo, dtype=float), np.asarray(item.hi, dtype=float)
    body = _nearest_body_origin(scene, lo, hi)
    if body is None:
        return _Lattice(lo, _counts(lo, hi, d), None)
    kmin = np.ceil((lo - body) / d - 0.5 - 1e-9)
    kmax = np.floor((hi - body) / d - 0.5 + 1e-9)
    origin = body + kmin * d
    origin = np.where(np.abs(origin - lo) < 1e-9 * d, lo, origin)  # on the grid already
    return _Lattice(origin, np.maximum(kmax - kmin + 1, 0).astype(np.int64), None)


def _lattice(scene: Scene, item, is_wall: bool) -> _Lattice:
    d, dim = scene.domain.particle_size, scene.domain.dim
    shape = item.shape
    if shape == "box":
        if is_wall:
            return _wall_box_lattice(scene, item)
        return _Lattice(item.lo, _counts(item.lo, item.hi, d), None)
    if shape == "tank":
        layers = wall_layers(scene, item)
        lo, hi = np.array(item.lo), np.array(item.hi)
        n_in = np.round((hi - lo) / d).astype(np.int64)
        origin = lo - layers * d
        sides = set(item.sides)
        names = SIDES[dim]

        def inside(x):
            keep = np.ones(len(x), dtype=bool)
            outside_any = np.zeros(len(x), dtype=bool)
            for ax in range(dim):
                below, above = x[:, ax] < lo[ax], x[:, ax] > hi[ax]
                outside_any |= below | above
                if names[2 * ax] not in sides:
                    keep &= ~below
                if names[2 * ax + 1] not in sides:
                    keep &= ~above
            return keep & outside_any

        def exact_count():
            # per axis the lattice is [below: layers | inside: n_in | above: layers]; a
            # point is kept when it is outside on some axis and on no axis beyond an
            # open side: sum over the 3**dim classes of the product of the class widths
            total = 0
            for cls in np.ndindex(*(3,) * dim):
                if all(c == 1 for c in cls):
                    continue  # the interior
                if any((c == 0 and names[2 * ax] not in sides)
                       or (c == 2 and names[2 * ax + 1] not in sides) for ax, c in enumerate(cls)):
                    continue
                total += int(np.prod([n_in[ax] if c == 1 else layers for ax, c in enumerate(cls)]))
            return total

        return _Lattice(origin, n_in + 2 * layers, inside, exact_count)
    if shape == "polygon":
        verts = np.array(item.vertices, dtype=float)
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        return _Lattice(lo, _counts(lo, hi, d) + 1,
                        lambda x: _points_in_polygon(x[:, 0], x[:, 1], verts))
    if shape == "extruded_polygon":
        verts = np.array(item.vertices, dtype=float)
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        y0, y1 = item.extent
        origin = (lo[0], y0, lo[1])
        counts = (_counts(lo[0], hi[0], d) + 1, _counts(y0, y1, d), _counts(lo[1], hi[1], d) + 1)
        return _Lattice(origin, counts, lambda x: _points_in_polygon(x[:, 0], x[:, 2], verts))
    if shape == "heightmap":
        grid = scene.data[item.top]
        (x0, x1), (y0, y1) = grid.extent
        # the highest node of every height map a body of the scene has on top
        ztop = max(scene.data[b.top].z.max() for b in scene.bodies if b.shape == "heightmap")
        below = item.below
        base = scene.data[item.bottom_surface] if item.bottom_surface else None
        if math.isfinite(item.bottom):
            zb = item.bottom
        elif item.depth > 0:
            zb = grid.z.min() - below - item.depth
        elif base is not None:
            zb = base.z.min()
        else:
            raise SceneError(f"{scene.source}: body '{item.name}': a heightmap body needs "
                             f"'bottom' (z of its base), 'depth' (thickness below the "
                             f"surface) or 'bottom_surface' (a grid of its base)")
        if base is not None:
            zb = max(zb, base.z.min())
        depth = item.depth
        # every height-map body hangs its lattice from the highest point of all of them,
        # so layers under layers, on one grid or on grids with the same nodes (a stack of
        # layer boundaries), meet without gaps or overlaps
        zb = ztop - math.ceil((ztop - zb) / d - 1e-9) * d

        def inside(x):
            top = surface(grid, x[:, 0], x[:, 1])
            keep = (x[:, 2] >= zb) & ((x[:, 2] < top - below) if below > 0 else
                                      (x[:, 2] <= top))
            if depth > 0:
                keep &= x[:, 2] >= top - below - depth
            if base is not None:
                # strictly above: a point on a surface shared with the top of the body
                # below belongs to that body (whose top is inclusive), never to both
                keep &= x[:, 2] > surface(base, x[:, 0], x[:, 1])
            return keep

        return _Lattice((x0, y0, zb), _counts((x0, y0, zb), (x1, y1, ztop), d), inside)
    if shape == "mesh":
        return _mesh_lattice(scene, item, is_wall)
    raise SceneError(f"{scene.source}: unknown shape '{shape}' for '{item.name}'")


#: Mesh lattices with at most this many columns are counted exactly; larger ones from a
#: sample (see :meth:`parsph.scene.mesh.MeshFill.count`): about a second of rays either way.
_MESH_COLUMNS = 1 << 14


def _mesh_lattice(scene: Scene, item, is_wall: bool) -> _Lattice:
    """A mesh's lattice: its bounding box on the domain's lattice (``domain.lo + (k + 1/2)
    d``), grown by the wall layers for an ``outside`` wall; filled by columns."""
    from parsph.scene.mesh import MeshFill

    d = scene.domain.particle_size
    mesh = scene.data[f"mesh:{item.name}"]
    layers = wall_layers(scene, item) if is_wall else 0
    grow = layers if is_wall and item.fill == "outside" else 0
    dlo = np.array(scene.domain.lo, dtype=float)
    origin = dlo + (np.floor((mesh.lo - dlo) / d + 1e-9) - grow) * d
    counts = np.ceil((mesh.hi - origin) / d - 1e-9).astype(np.int64) + grow
    fill = MeshFill(mesh, origin, d, layers, item.fill if is_wall else "inside")

    def inside(x):
        return fill.inside(np.rint((x - origin) / d - 0.5).astype(np.int64))

    def exact_count():
        return fill.count(counts, _MESH_COLUMNS, np.random.default_rng(12345))

    return _Lattice(origin, counts, inside, exact_count)


def estimate_count(scene: Scene) -> int:
    """The particle count of a scene, without generating it (see :meth:`_Lattice.kept`).

    Exact for boxes and tanks and for small filtered lattices; a sampled upper bound for
    large polygons and heightmaps. (The lattice candidates, which this used to return,
    overcount a hollow tank by its interior: 5.6x for ``dam_break``.)
    """
    d = scene.domain.particle_size
    return sum(_lattice(scene, it, False).kept(d) for it in scene.bodies) + \
        sum(_lattice(scene, it, True).kept(d) for it in scene.walls)


def _generate_item(comm, scene: Scene, lat: _Lattice, first_id: int):
    """This rank's share of one lattice: positions and ids (lattice order)."""
    d = scene.domain.particle_size
    total = lat.total
    start = total * comm.rank // comm.size
    stop = total * (comm.rank + 1) // comm.size
    parts, error = [], None
    try:  # an inside test that fails on one rank (a mesh's rays) fails on all
        for a in range(start, stop, _CHUNK):
            idx = np.arange(a, min(a + _CHUNK, stop), dtype=np.int64)
            x = lat.points(idx, d)
            if lat.inside is not None:
                x = x[lat.inside(x)]
            parts.append(x)
    except SceneError as exc:
        error = exc
    raise_if_any(comm, error)
    x = np.concatenate(parts) if parts else np.zeros((0, scene.domain.dim))
    offset, count = global_offset(comm, len(x))
    ids = first_id + offset + np.arange(len(x), dtype=np.int64)
    return x, ids, count


def _density(material) -> float:
    """Reference density rho_0 of a material: (1 - n_0) rho_s for soils (section 3.1)."""
    return getattr(material, "reference_density", material.density)


def generate(comm, scene: Scene) -> dict:
    """Collective: this rank's share of all particles (before partitioning).

    Returns
    -------
    dict
        Core fields (see :data:`parsph.core.particles.CORE_FIELDS`); ``body`` is the index of
        the particle's body or wall in ``scene.bodies + scene.walls`` (walls after bodies).
    """
    dim = scene.domain.dim
    d = scene.domain.particle_size
    names = list(scene.materials)
    mats = [scene.materials[n] for n in names]
    fluid_mats = [m for m in mats if m.phase == 1]
    wall_density = _density(fluid_mats[0]) if fluid_mats else 1000.0
    out = {k: [] for k in ("id", "x", "v", "m", "phase", "material", "body")}
    next_id = 0
    body_index = 0
    for is_wall, items in ((False, scene.bodies), (True, scene.walls)):
        for item in items:
            x, ids, count = _generate_item(comm, scene, _lattice(scene, item, is_wall), next_id)
            next_id += count
            n = len(x)
            if is_wall:
                density, phase, mat, vel = wall_density, PHASE_WALL, -1, ()
            else:
                material = scene.materials[item.material]
                density, phase, mat, vel = (_density(material), material.phase,
                                            names.index(item.material), item.velocity)
            out["id"].append(ids)
            out["x"].append(x)
            v = np.zeros((n, dim))
            if vel:
                v[:] = vel
            out["v"].append(v)
            out["m"].append(np.full(n, density * d ** dim))
            out["phase"].append(np.full(n, phase, dtype=np.uint8))
            out["material"].append(np.full(n, mat, dtype=np.int16))
            out["body"].append(np.full(n, body_index, dtype=np.int16))
            body_index += 1
    dtypes = {"id": np.int64, "phase": np.uint8, "material": np.int16, "body": np.int16}
    fields = {}
    for k, parts in out.items():
        if parts:
            fields[k] = np.concatenate(parts).astype(dtypes.get(k, np.float64), copy=False)
        else:
            shape = (0, dim) if k in ("x", "v") else (0,)
            fields[k] = np.zeros(shape, dtype=dtypes.get(k, np.float64))
    return fields


def _geometry_box(scene: Scene, item):
    """The bounding box (lo, hi) of a body's geometry as written, and its measure (area in
    2D, volume in 3D) where the shape gives it in closed form (else None)."""
    shape = item.shape
    if shape == "box":
        lo, hi = np.asarray(item.lo, dtype=float), np.asarray(item.hi, dtype=float)
        return lo, hi, float(np.prod(hi - lo))
    if shape in ("polygon", "extruded_polygon"):
        verts = np.array(item.vertices, dtype=float)
        x, y = verts[:, 0], verts[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        if shape == "polygon":
            return lo, hi, area
        y0, y1 = item.extent
        return (np.array([lo[0], y0, lo[1]]), np.array([hi[0], y1, hi[1]]),
                area * (y1 - y0))
    if shape == "heightmap":
        lat = _lattice(scene, item, False)
        grid = scene.data[item.top]
        (x0, x1), (y0, y1) = grid.extent
        return (np.array([x0, y0, lat.origin[2]]),
                np.array([x1, y1, float(np.nanmax(grid.z))]), None)
    if shape == "mesh":
        mesh = scene.data[f"mesh:{item.name}"]
        return np.asarray(mesh.lo, dtype=float), np.asarray(mesh.hi, dtype=float), None
    return None, None, None


def fitting_size(item, d: float, tries: int = 64):
    """The particle size nearest ``d`` whose lattice meets every vertex coordinate of a
    polygon body (each offset from the lower corner a whole number of sizes), or None.

    A polygon's lattice starts at its lower corner and keeps the centres ``(k + 1/2) d``
    inside it, so an edge at an offset that is not a multiple of d is met up to d/2 short
    or long (the slope's 1 m at d = 0.0177 m stands 0.991 m tall, docs/slope.md)."""
    if item.shape not in ("polygon", "extruded_polygon"):
        return None
    verts = np.array(item.vertices, dtype=float)
    offsets = verts - verts.min(axis=0)
    if item.shape == "extruded_polygon":  # and its extent along y
        offsets = np.append(offsets, item.extent[1] - item.extent[0])
    offsets = np.unique(np.round(offsets, 12))
    offsets = offsets[offsets > 0]
    if not len(offsets):
        return None
    span = float(offsets.max())
    n0 = max(1, int(round(span / d)))
    for step in range(tries):
        for n in sorted({n0 - step, n0 + step}):
            if n < 1:
                continue
            size = span / n
            k = offsets / size
            if np.all(np.abs(k - np.round(k)) < 1e-6):
                return size
    return None


def body_fill(comm, scene: Scene, fields: dict) -> list[dict]:
    """Collective: how the lattice fills each body, beside its geometry as written.

    ``fields`` are :func:`generate`'s (any distribution over the ranks). Per body: the
    particle count, the filled extent (the outermost centres -/+ d/2 per axis), the filled
    measure ``n d^dim``, and the geometry's bounding box and measure (None where the shape
    has no closed form: heightmaps, meshes). The same on every rank."""
    from decomposition.reduce import global_reduce

    d, dim = scene.domain.particle_size, scene.domain.dim
    nb = len(scene.bodies)
    counts, maxs, mins = [], [], []
    for b in range(nb):
        x = fields["x"][fields["body"] == b]
        counts.append(float(len(x)))
        maxs += list(x.max(axis=0)) if len(x) else [-np.inf] * dim
        mins += list(x.min(axis=0)) if len(x) else [np.inf] * dim
    counts, maxs, mins = global_reduce(comm, counts, maxs, mins)
    out = []
    for b, item in enumerate(scene.bodies):
        glo, ghi, measure = _geometry_box(scene, item)
        n = int(counts[b])
        lo = np.array(mins[b * dim:(b + 1) * dim]) - 0.5 * d
        hi = np.array(maxs[b * dim:(b + 1) * dim]) + 0.5 * d
        out.append({"name": item.name, "shape": item.shape, "particles": n,
                    "lo": lo if n else None, "hi": hi if n else None,
                    "measure": n * d ** dim, "geometry_lo": glo, "geometry_hi": ghi,
                    "geometry_measure": measure})
    return out


def fill_warnings(scene: Scene, fills: list[dict]) -> list[str]:
    """Warnings for polygon bodies the lattice stands more than d/4 short of or beyond on
    an axis (boxes have theirs in :func:`geometry_warnings`): a slope
    whose height the lattice does not meet is driven by a different height at each d, which
    a convergence study then reads as the method's error (docs/slope.md)."""
    d = scene.domain.particle_size
    out = []
    for fill, item in zip(fills, scene.bodies):
        if item.shape not in ("polygon", "extruded_polygon") or fill["lo"] is None:
            continue
        ext = fill["hi"] - fill["lo"]
        gext = fill["geometry_hi"] - fill["geometry_lo"]
        axes = np.flatnonzero(np.abs(ext - gext) > 0.25 * d)
        if not len(axes):
            continue
        size = fitting_size(item, d)
        hint = (f"d = {size:.4g} m meets every vertex" if size else
                "no size near d meets every vertex; choose d dividing its extents")
        spans = "; ".join(f"along axis {a} it spans {gext[a]:g} m, filled {ext[a]:.4g} m "
                          f"({100 * (ext[a] - gext[a]) / gext[a]:+.1f} %)" for a in axes)
        out.append(f"body '{fill['name']}' is not met by the lattice of d = {d:g} m: "
                   f"{spans}; the body as filled changes with d (docs/geometry.md); {hint}")
    return out


def geometry_warnings(scn: Scene) -> list[str]:
    """Warnings about a geometry the particle size does not resolve as written.

    - A box wall thinner than the kernel support 2h on its thinnest axis: a particle
      next to it sees an incomplete wall, the fluid's wall pressure and the solid's
      contact normal are weak, and a particle can pass through it (a box floor of 0.15 m
      at d = 0.1 m, 2h = 0.24 m, let the slope fall through). Tanks and polygons get
      enough layers by default (``layers = 0``).
    - A periodic axis whose period is not a whole number of particle sizes: the particles
      either side of the periodic boundary stand further apart than d (``slope_failure_3d``
      at d = 0.04 m: 6 layers across its 0.25 m, a 0.05 m seam).
    - A box body whose extent is not a whole number of particle sizes: the lattice
      leaves the remainder empty at its upper side (at d = 0.0667 m the 1 m
      ``hydrostatic`` column leaves a 0.066 m gap at the right wall, and the water
      collapses into it instead of resting).
    """
    from parsph.core.kernel import smoothing_length, support_radius

    d = scn.domain.particle_size
    reach = support_radius(smoothing_length(d))
    out = []
    for wall in scn.walls:
        if wall.shape == "box":
            thick = float(np.min(np.array(wall.hi) - np.array(wall.lo)))
            if thick < reach - 1e-9:
                out.append(f"wall '{wall.name}' is {thick:g} m thick, less than the kernel "
                           f"support 2h = {reach:g} m at d = {d:g} m: particles may pass "
                           f"through it; make it at least {reach:g} m thick")
    span = np.array(scn.domain.hi) - np.array(scn.domain.lo)
    for axis in np.flatnonzero(np.array(scn.domain.periodic, dtype=bool)):
        seam = span[axis] - np.floor(span[axis] / d + 1e-9) * d
        if min(seam, d - seam) > 1e-6 * d:
            out.append(f"the domain is periodic along axis {axis} over {span[axis]:g} m, not a "
                       f"whole number of particles of d = {d:g} m: the particles either side "
                       f"of the periodic boundary stand {d + seam:.3g} m apart instead of d; "
                       f"choose d = "
                       f"{span[axis]:g} / N (e.g. {span[axis] / max(1, round(span[axis] / d)):.4g} m)")
    for body in scn.bodies:
        if body.shape == "box":
            extent = np.array(body.hi) - np.array(body.lo)
            gap = extent - np.floor(extent / d + 1e-9) * d
            for axis in np.flatnonzero(gap > 0.25 * d):
                out.append(f"body '{body.name}' spans {extent[axis]:g} m along axis {axis}, "
                           f"not a whole number of particles of d = {d:g} m: the lattice "
                           f"leaves {gap[axis]:.3g} m empty at its upper side (a fluid "
                           f"collapses into such a gap); choose d = extent / N")
    return out
