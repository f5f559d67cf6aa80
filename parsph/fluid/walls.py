"""Which slip condition (no-slip / free-slip) a wall particle has.

Every particle carries ``body``, the index of the body or wall it was generated from in
``scene.bodies + scene.walls`` (walls after the bodies); a wall particle's slip is the
``slip`` key of its wall.
"""
from __future__ import annotations

import numpy as np

NO_SLIP, FREE_SLIP = 0, 1


def wall_slip(scene, body, is_wall) -> np.ndarray:
    """Slip flag (uint8, 1 = free-slip) of every row; 0 for rows that are not walls.

    Parameters
    ----------
    scene : parsph.scene.loader.Scene
    body : numpy.ndarray of int, shape (N,)
        Body/wall index of every row (the ``body`` field).
    is_wall : numpy.ndarray of bool, shape (N,)

    Returns
    -------
    numpy.ndarray of uint8, shape (N,)
    """
    free = np.array([w.slip == "free_slip" for w in scene.walls] + [False], dtype=np.uint8)
    slip = np.zeros(len(body), dtype=np.uint8)
    wall = np.asarray(body)[is_wall] - len(scene.bodies)
    slip[is_wall] = free[np.where((wall >= 0) & (wall < len(scene.walls)), wall, -1)]
    return slip
