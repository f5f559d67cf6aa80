"""Triangle meshes (STL, OBJ) as bodies and walls: read, checked, placed, filled.

A mesh is read once, on rank 0 while the scene is loaded (:func:`read_mesh`, with
trimesh), checked to be a closed surface, and placed in scene units. Every rank then
fills its own share of the particle lattice with :class:`MeshFill`.

Notes
-----
The inside test is a parity test along lattice columns. The lattice has spacing ``d``
and points at ``origin + (i + 1/2, j + 1/2, k + 1/2) d``; all points of a column
``(i, j)`` share one vertical ray, cast upward from below the mesh with trimesh's ray
tests (``trimesh.ray.ray_triangle``, an rtree of the triangles' boxes). A point is
inside when an odd number of the ray's crossings lie at or below it. One ray serves
``nz`` points: 1e6 lattice points of a 5,120-triangle sphere take 1e4 rays, 1.3 s in all
(trimesh's own ``contains``, one ray per point, took 21 s and 2.9 GB for 1e5 points).

The ray of column ``(i, j)`` is shifted by ``1e-6 d`` in a fixed direction, so that it
does not run exactly through an edge or a vertex of a mesh drawn on round numbers; a
column whose ray still crosses an odd number of times (it grazed an edge) is cast again
with another shift. The classification of a point therefore depends only on its lattice
indices, never on which rank tests it or with which other points: the particle set does
not depend on the rank count.

Wall layers (``fill = "inside"``): the lattice points inside the surface that have a
lattice point outside it within ``layers d``; ``"outside"``: the points outside with a
point inside within ``layers d``. On a flat face both give exactly ``layers`` layers. A
rank evaluates the inside test on the box of its lattice points grown by ``layers``
on every side, so no neighbour's answer is needed.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from parsph.errors import SceneError

#: File extensions read as meshes (trimesh's loaders; STL binary or ASCII).
EXTENSIONS = (".stl", ".obj")
#: Shifts of a column's ray (units of 1e-6 d): tried in turn for columns whose ray
#: crosses the surface an odd number of times.
_SHIFTS = ((0.318309886, 0.223606798), (-0.271828183, 0.141421356), (0.173205081, -0.316227766))
_SHIFT = 1e-6


@dataclass(frozen=True, eq=False)
class Mesh:
    """A closed triangle surface placed in scene units (m).

    Attributes
    ----------
    path : str
        The file it was read from.
    vertices : ndarray (nv, 3)
        Vertex positions after scale, rotate and translate (m).
    faces : ndarray (nf, 3) int64
        Vertex indices of each triangle.
    """

    path: str
    vertices: np.ndarray
    faces: np.ndarray

    @property
    def lo(self) -> np.ndarray:
        return self.vertices.min(axis=0)

    @property
    def hi(self) -> np.ndarray:
        return self.vertices.max(axis=0)


def rotation(degrees) -> np.ndarray:
    """Rotation matrix of angles (degrees) about x, then y, then z (fixed axes)."""
    ax, ay, az = (math.radians(float(a)) for a in degrees)
    cx, sx, cy, sy, cz, sz = (math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay),
                              math.cos(az), math.sin(az))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def read_mesh(path: str, key: str, source: str, scale: float = 1.0, rotate=(),
              translate=()) -> Mesh:
    """Read an STL (binary or ASCII) or OBJ file and place it: ``x' = R (scale x) + t``.

    Raises
    ------
    SceneError
        If the file is missing, not a mesh trimesh reads, empty, or not watertight (an
        inside test needs a closed surface); the message names the file and ``key``.
    """
    import trimesh

    where = f"{source}: key '{key}': "
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSIONS:
        raise SceneError(f"{where}mesh file '{path}' has extension '{ext}'; parsph reads "
                         f"{', '.join(EXTENSIONS)} (STL binary or ASCII, Wavefront OBJ)")
    if not os.path.isfile(path):
        raise SceneError(f"{where}mesh file '{path}' does not exist (paths are relative to "
                         f"the scene file)")
    try:
        loaded = trimesh.load(path, file_type=ext[1:], force="mesh")
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64)
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
        raise SceneError(f"{where}cannot read mesh file '{path}' as {ext[1:].upper()}: "
                         f"{type(exc).__name__}: {exc}") from None
    if len(faces) == 0:
        raise SceneError(f"{where}mesh file '{path}' has no triangles")
    if not np.all(np.isfinite(vertices)):
        raise SceneError(f"{where}mesh file '{path}' has NaN or infinite vertices")
    # drop texture/normal seams (they split vertices) and merge by position
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True)
    if not mesh.is_watertight:
        edges = np.sort(mesh.edges, axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        raise SceneError(f"{where}mesh '{path}' is not watertight: {int((counts != 2).sum())} "
                         f"of its {len(counts)} edges do not join exactly two triangles; the "
                         f"inside test needs a closed surface: close its holes (or remove "
                         f"duplicate faces) in a mesh tool")
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * scale
    if rotate:
        vertices = vertices @ rotation(rotate).T
    if translate:
        vertices = vertices + np.asarray(translate, dtype=np.float64)
    return Mesh(path=path, vertices=vertices, faces=np.asarray(mesh.faces, dtype=np.int64))


def ball_offsets(radius: int) -> np.ndarray:
    """Lattice offsets (n, 3) with ``|o| <= radius`` (units of d), the zero offset excluded."""
    r = np.arange(-radius, radius + 1)
    o = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    keep = (o ** 2).sum(axis=1) <= radius ** 2
    keep &= np.any(o != 0, axis=1)
    return o[keep]


class MeshFill:
    """The inside test of a mesh on a lattice, by columns (see the module notes).

    Parameters
    ----------
    mesh : Mesh
    origin : array (3,)
        Lattice origin (m): points at ``origin + (idx + 1/2) d``.
    d : float
        Particle spacing (m).
    layers : int
        0: the filled interior (bodies); else the wall layers on side ``fill``.
    fill : {"inside", "outside"}
    """

    def __init__(self, mesh: Mesh, origin, d: float, layers: int = 0, fill: str = "inside"):
        self.mesh = mesh
        self.origin = np.asarray(origin, dtype=np.float64)
        self.d = float(d)
        self.layers = int(layers)
        self.fill = fill
        self._triangles = None  # the non-degenerate triangles and their rtree, built on first use
        self._tree = None

    # -- rays
    def _cast(self, ci, cj, shift):
        """Crossings of the rays of columns (ci, cj): (column number, z) of each hit."""
        from trimesh import triangles as tri
        from trimesh.ray.ray_triangle import ray_triangle_id

        if self._tree is None:
            triangles = self.mesh.vertices[self.mesh.faces]
            _, ok = tri.normals(triangles)  # zero-area triangles cross no ray
            self._triangles = triangles[ok]
            self._tree = tri.bounds_tree(self._triangles)
        d = self.d
        x = self.origin[0] + (ci + 0.5) * d + shift[0] * _SHIFT * d
        y = self.origin[1] + (cj + 0.5) * d + shift[1] * _SHIFT * d
        z = np.full(len(ci), self.mesh.lo[2] - 1.0 - d)
        rays = np.column_stack([x, y, z])
        up = np.tile((0.0, 0.0, 1.0), (len(ci), 1))
        _, ray, loc = ray_triangle_id(self._triangles, rays, up, tree=self._tree,
                                      multiple_hits=True)
        z_hit = np.asarray(loc, dtype=np.float64).reshape(-1, 3)[:, 2]
        return np.asarray(ray, dtype=np.int64), z_hit

    def crossings(self, ci, cj):
        """Per column (ci, cj): the sorted lattice heights ``kk`` of its crossings.

        ``kk`` is the first ``k`` whose point is at or above the crossing; a point ``k``
        is inside when an odd number of its column's ``kk`` are ``<= k``.

        Returns
        -------
        ptr : ndarray (n + 1,) int64
            Column ``c`` has the crossings ``kk[ptr[c]:ptr[c + 1]]``.
        kk : ndarray int64
        """
        n = len(ci)
        col = np.zeros(0, dtype=np.int64)
        zs = np.zeros(0)
        todo = np.arange(n)
        for shift in _SHIFTS:
            if len(todo) == 0:
                break
            ray, z = self._cast(ci[todo], cj[todo], shift)
            odd = np.bincount(ray, minlength=len(todo)) % 2 == 1
            good = ~odd[ray]
            col = np.concatenate([col, todo[ray[good]]])
            zs = np.concatenate([zs, z[good]])
            todo = todo[odd]
        if len(todo):
            raise SceneError(f"mesh '{self.mesh.path}': the vertical rays through {len(todo)} "
                             f"lattice columns cross its surface an odd number of times however "
                             f"they are shifted; the mesh is not a closed surface there: "
                             f"repair it in a mesh tool")
        kk = np.ceil((zs - self.origin[2]) / self.d - 0.5).astype(np.int64)
        order = np.lexsort((kk, col))
        ptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(col, minlength=n), out=ptr[1:])
        return ptr, kk[order]

    # -- inside tests
    def inside_indices(self, idx) -> np.ndarray:
        """Inside test of lattice points ``idx`` (n, 3) int64 (any set, e.g. a sample)."""
        if len(idx) == 0:
            return np.zeros(0, dtype=bool)
        j0 = int(idx[:, 1].min())
        span = int(idx[:, 1].max()) - j0 + 1
        cols, inv = np.unique(idx[:, 0] * span + (idx[:, 1] - j0), return_inverse=True)
        ptr, kk = self.crossings(cols // span, cols % span + j0)
        k = idx[:, 2]
        k0, k1 = int(k.min()), int(k.max())
        width = k1 - k0 + 3
        ncross = np.diff(ptr)
        hit_col = np.repeat(np.arange(len(cols), dtype=np.int64), ncross)
        hit_key = hit_col * width + (np.clip(kk, k0 - 1, k1 + 1) - k0 + 1)
        point_key = inv * width + (k - k0 + 1)
        below = np.searchsorted(hit_key, point_key, side="right") - ptr[inv]
        return below % 2 == 1

    def mask_box(self, lo, hi) -> np.ndarray:
        """Inside test of every lattice point of the index box ``[lo, hi)`` (3 ints each)."""
        lo, hi = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
        ni, nj, nk = (hi - lo).tolist()
        ci, cj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]), indexing="ij")
        ptr, kk = self.crossings(ci.ravel(), cj.ravel())
        hit_col = np.repeat(np.arange(ni * nj, dtype=np.int64), np.diff(ptr))
        toggles = np.zeros((ni * nj, nk + 1), dtype=np.uint8)
        np.add.at(toggles, (hit_col, np.clip(kk - lo[2], 0, nk)), 1)
        mask = np.cumsum(toggles, axis=1, dtype=np.uint8)[:, :nk] & 1
        return mask.astype(bool).reshape(ni, nj, nk)

    def wall_box(self, lo, hi) -> np.ndarray:
        """Wall layers on the index box ``[lo, hi)``: the inside test on the box grown by
        ``layers``, then the points on side ``fill`` with a point of the other side within
        ``layers`` (lattice offsets of length <= layers)."""
        r = self.layers
        lo, hi = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
        grown = self.mask_box(lo - r, hi + r)
        side = grown if self.fill == "inside" else ~grown
        n = hi - lo
        core = (slice(r, r + n[0]), slice(r, r + n[1]), slice(r, r + n[2]))
        near_other = np.zeros(tuple(n), dtype=bool)
        for o in ball_offsets(r):
            s = tuple(slice(r + o[a], r + o[a] + n[a]) for a in range(3))
            near_other |= ~side[s]
        return side[core] & near_other

    def inside(self, idx) -> np.ndarray:
        """The fill of lattice points ``idx`` (n, 3): interior (bodies) or wall layers.

        Wall layers are evaluated on the index box of ``idx`` (a contiguous range of the
        lattice when a rank generates its share; a random sample only when counting).
        """
        if self.layers == 0:
            return self.inside_indices(idx)
        if len(idx) == 0:
            return np.zeros(0, dtype=bool)
        lo, hi = idx.min(axis=0), idx.max(axis=0) + 1
        box = self.wall_box(lo, hi)
        rel = idx - lo
        return box[rel[:, 0], rel[:, 1], rel[:, 2]]

    # -- counting without generating
    def count(self, counts, sample: int, rng) -> int:
        """Points of the lattice ``counts`` this fill keeps: exact when the lattice has at
        most ``sample`` columns, else an upper bound from random columns (the mean plus
        four standard errors, times the columns): ``sample`` of them for a body; for a
        wall ``sample / 64``, each evaluated with its ``(2 layers + 1)^2`` neighbours.
        """
        nx, ny, nz = (int(c) for c in counts)
        ncols = nx * ny
        if ncols == 0 or nz == 0:
            return 0
        if ncols <= sample:
            if self.layers == 0:
                ci, cj = np.divmod(np.arange(ncols, dtype=np.int64), ny)
                return int(self._column_counts(ci, cj, nz).sum())
            rows = max(1, sample // (4 * ny))
            return sum(int(self.wall_box((a, 0, 0), (min(a + rows, nx), ny, nz)).sum())
                       for a in range(0, nx, rows))
        n = sample if self.layers == 0 else max(sample // 64, 16)
        ci, cj = np.divmod(rng.choice(ncols, size=n, replace=False).astype(np.int64), ny)
        if self.layers == 0:
            per = self._column_counts(ci, cj, nz)
        else:
            per = np.array([int(self.wall_box((i, j, 0), (i + 1, j + 1, nz)).sum())
                            for i, j in zip(ci, cj)])
        # standard error of the mean, sampled without replacement from ncols columns
        err = float(per.std(ddof=1)) / math.sqrt(n) * math.sqrt((ncols - n) / (ncols - 1))
        return min(ncols * nz, int(math.ceil((float(per.mean()) + 4.0 * err) * ncols)))

    def _column_counts(self, ci, cj, nz) -> np.ndarray:
        """Inside points of each column (ci, cj) of height nz: the inside runs' lengths."""
        ptr, kk = self.crossings(ci, cj)
        kk = np.clip(kk, 0, nz)
        sign = np.where((np.arange(len(kk)) - np.repeat(ptr[:-1], np.diff(ptr))) % 2 == 0, -1, 1)
        return np.bincount(np.repeat(np.arange(len(ci)), np.diff(ptr)), weights=sign * kk,
                           minlength=len(ci)).astype(np.int64)
