"""The current-configuration halo of a coupled scene: the rows near each rank's fluid
and near its rows that the fluid can wet (the mixed layout, docs/decomposition.md)."""
from __future__ import annotations

import numpy as np

from decomposition.box import masked_bounds
from decomposition.halo import Halo, _box_images, _image_send_lists, _near_boxes

__all__ = ["coupled_halo"]


def coupled_halo(comm, x_owned, fluid, radius: float, box=None) -> Halo:
    """Collective: the current-configuration halo of a coupled scene (mixed layout).

    The current-configuration lists serve the IISPH step only (``Context.wet_lists``):
    a fluid row has one, and a wall or solid row only when a fluid row is within
    ``radius`` (then its whole neighbourhood: the type-II test, the support density
    that decides its contact). Rank ``q`` therefore receives every row within
    ``radius`` of the bounding box of its fluid rows, and of the bounding box of its
    other rows that lie within ``2 radius`` of any rank's fluid box (the rows that can
    be wet: its *wet box*), and every fluid row within ``2 radius`` of its wet box (the
    walls within two radii of the fluid make the PPE's band,
    :func:`parsph.fluid.walls.system_rows`). Rows are owned by two partitions (solids by
    their reference position, fluid and walls by their current one), so a rank's rows
    form compact groups, but its solid and wall boxes reach far beyond the fluid: with
    those boxes the two ranks of the 3D tank of ``jobs/bench_memory.py`` received
    10,093 and 6,906 halo rows, of which their lists used 2,593 each.

    No copies to self except periodic images: with a periodic ``box`` every rank,
    itself included, also gets the images of the rows within reach of its boxes (the
    exchange shifts their ``x`` and ``X``). A negative ``radius`` gives an empty pattern
    (no fluid anywhere).

    Parameters
    ----------
    x_owned : ndarray (n_owned, dim)
        Current positions (m).
    fluid : ndarray of bool (n_owned,)
        The owned fluid rows.
    radius : float
        Reach (m), the kernel support 2h.
    """
    x = np.asarray(x_owned, dtype=float)
    if comm.size == 1 and not (box is not None and box.any_periodic):  # nothing to copy
        return Halo._from_flat(comm, np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64),
                               None, len(x))
    fluid = np.asarray(fluid, dtype=bool)
    dim = x.shape[1] if x.ndim == 2 else 0
    x = np.ascontiguousarray(x.reshape(len(x), dim), dtype=np.float64)
    shifts = np.ascontiguousarray(_box_images(box, dim), dtype=np.float64)
    empty = (np.full(dim, np.inf), np.full(dim, -np.inf))
    if radius < 0:
        fbox = wbox = empty
    else:
        fbox = masked_bounds(x, fluid)
    fluid_boxes = [b[0] for b in _gather_boxes(comm, (fbox,)) if not np.any(b[0][0] > b[0][1])]
    if radius >= 0 and fluid_boxes:
        # the rows but the fluid that lie (an image of them) within 2 radii of any fluid box
        flo = np.array([b[0] for b in fluid_boxes], dtype=np.float64)
        fhi = np.array([b[1] for b in fluid_boxes], dtype=np.float64)
        reach = np.full(len(flo), 2.0 * radius)
        only, dry = np.ones(len(flo), dtype=np.bool_), ~fluid
        wet = np.zeros(len(x), dtype=np.bool_)
        for s in shifts:
            wet |= _near_boxes(x, s, flo, fhi, reach, only, dry)
        wbox = masked_bounds(x, wet)
    elif radius >= 0:
        wbox = empty
    boxes = _gather_boxes(comm, (fbox, wbox))
    periodic = box is not None and box.any_periodic
    # every row near the fluid box or the wet box; the fluid rows within 2 radii of the
    # wet box; to itself only the periodic images
    boxes_of = [[f, w, (w[0], w[1], 2.0 * radius, True)] for f, w in boxes]
    send, shift = _image_send_lists(comm, x, boxes_of, radius, shifts, False, fluid)
    # lists made here are valid by construction: no agreement on them (a collective)
    flat = np.concatenate(send) if send else np.zeros(0, dtype=np.int64)
    return Halo._from_flat(comm, flat.astype(np.int64, copy=False),
                           np.array([len(i) for i in send], dtype=np.int64),
                           np.concatenate(shift) if periodic else None, len(x))


def _gather_boxes(comm, boxes):
    """Collective: every rank's ``boxes`` (a tuple of ``(lo, hi)`` pairs of one length on
    every rank), as a list per rank of ``(lo, hi)`` float64 arrays: one ``Allgather`` of
    a buffer where the pickled ``allgather`` took 30-60 us of each 2-rank step."""
    mine = np.array([[np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)]
                     for lo, hi in boxes])
    every = np.empty((comm.size,) + mine.shape)
    comm.Allgather(mine, every)
    return [[(b[0], b[1]) for b in rank] for rank in every]
