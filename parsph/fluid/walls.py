"""Which wall a wall particle belongs to, hence its slip condition (no-slip / free-slip).

The particle set carries no wall index: wall particles are phase 2 with material -1.
A wall is fixed, so a wall particle's reference position ``X`` is its generated lattice
point, and the wall it came from is found again by testing ``X`` against each wall's
lattice (:func:`parsph.geometry._lattice`: the same bounding lattice and inside test that
generated it). Walls are tested in scene order and the first one that contains the
point wins, which is also the wall that generated it unless two walls overlap (then
both claim the point; the scene order decides, as documented in ``docs/iisph.md``).
"""
from __future__ import annotations

import numpy as np

from parsph.geometry import _lattice

NO_SLIP, FREE_SLIP = 0, 1


def _member(scene, wall, X) -> np.ndarray:
    """Points of ``X`` that are lattice points of ``wall`` and pass its inside test."""
    d = scene.domain.particle_size
    lat = _lattice(scene, wall, True)
    k = (X - lat.origin) / d - 0.5
    on_lattice = np.all(np.abs(k - np.round(k)) < 1e-6, axis=1)
    k = np.round(k)
    inside_box = np.all((k >= 0) & (k < lat.counts), axis=1)
    keep = on_lattice & inside_box
    if lat.inside is not None and keep.any():
        sel = np.flatnonzero(keep)
        keep[sel] = lat.inside(X[sel])
    return keep


def wall_slip(scene, X, is_wall) -> np.ndarray:
    """Slip flag (uint8, 1 = free-slip) of every row; 0 for rows that are not walls.

    Parameters
    ----------
    scene : parsph.scene.Scene
    X : numpy.ndarray, shape (N, dim)
        Reference (generated) positions (m).
    is_wall : numpy.ndarray of bool, shape (N,)

    Returns
    -------
    numpy.ndarray of uint8, shape (N,)
    """
    slip = np.zeros(len(X), dtype=np.uint8)
    kinds = {w.slip for w in scene.walls}
    if kinds <= {"no_slip"} or not is_wall.any():
        return slip
    if kinds == {"free_slip"}:
        slip[is_wall] = FREE_SLIP
        return slip
    todo = is_wall.copy()
    for wall in scene.walls:
        if not todo.any():
            break
        sel = np.flatnonzero(todo)
        hit = _member(scene, wall, X[sel])
        if wall.slip == "free_slip":
            slip[sel[hit]] = FREE_SLIP
        todo[sel[hit]] = False
    return slip
