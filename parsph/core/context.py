"""What the stages of a step see: the particles, the halo and neighbour lists, the
partition, the time, and the collective look-ups of nearby walls."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from decomposition.box import Box
from decomposition.halo import Halo
from decomposition.partition import RCB
from parsph.core.particles import PHASE_WALL, ParticleSet


@dataclass
class Context:
    """What the stages of a step see."""

    scene: object
    comm: object
    particles: ParticleSet
    box: Box
    dim: int
    d: float
    h: float
    radius: float
    rcb: RCB = None
    rcb_ref: RCB = None
    #: mixed layout: the walls' partition (``rcb`` is then the fluid's)
    rcb_wall: RCB = None
    #: set when the solids' partition (by X) was rebuilt: their view must be rebuilt too
    solids_moved: bool = False
    halo: Halo = None
    indptr: np.ndarray = None
    indices: np.ndarray = None
    layout: str = "current"
    key: str = "x"
    #: The current-configuration lists serve only an IISPH step (the iisph or coupled
    #: stage), whose kernels read a boundary row's neighbours only when the fluid touches
    #: it: a wall or solid row then gets its list only when a fluid row is within reach.
    wet_lists: bool = False
    restarted: bool = False
    out: str = ""
    materials: list = field(default_factory=list)
    time: float = 0.0
    step: int = 0
    timers: dict = field(default_factory=dict)
    #: Lagged migration (current layout with a fluid): an owned particle may stray this
    #: far (m) beyond its rank's sub-box before it must move; the halo is this much wider.
    skin: float = 0.0
    #: ... and strays move every this many steps (when the AMG set-up is renewed).
    migrate_every: int = 1
    #: Sync steps (``step % sync_every == 0``): strays move to their owners and the PPE's
    #: next solve sets up afresh; checkpoints and the end of a run fall on them (see
    #: :func:`run`). ``fluid.preconditioner_reuse`` with an implicit fluid, else 1.
    sync_every: int = 1
    sync_point: bool = False

    @property
    def n_owned(self) -> int:
        return self.particles.n_owned

    def update_halo(self, names) -> None:
        """Refresh the halo rows of the named fields from their owners (same pattern)."""
        p = self.particles
        fresh = self.halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))
        for name, rows in fresh.items():
            p[name][p.n_owned:] = rows

    def nearby_walls(self, names, around=None) -> dict:
        """Collective: the named fields of every wall row near this rank's particles
        (``around``: bool mask of owned rows, default all), see :meth:`nearby`."""
        p = self.particles
        return self.nearby(p["phase"][: p.n_owned] == PHASE_WALL, names, around=around)

    def body_acceleration(self, t: float) -> np.ndarray:
        """g − s a_ground(t − t_0) (m/s²): gravity and the earthquake record, section 6.3.

        The walls are fixed, so the record acts in the frame moving with the ground
        (see :mod:`parsph.scene.loading`); without a record this is g.
        """
        record = self.scene.data.get("record")
        if record is None:
            return self.gravity
        load = self.scene.loading
        return self.gravity - load.scale * record.at(t - load.start_time)

    @property
    def gravity(self) -> np.ndarray:
        return np.asarray(self.scene.gravity.g, dtype=float)

    def nearby(self, select, names, radius: float | None = None, around=None) -> dict:
        """Collective: owned rows of every rank (``select`` mask) near this rank's particles.

        ``around`` (bool mask of owned rows, default all) chooses the particles whose
        current bounding box, widened by ``radius`` (default 2h), defines "near". Returns
        the named fields of those rows, this rank's own included. Used for neighbours in
        the current configuration when ownership follows the reference one (walls seen
        by TLSPH particles).
        """
        from decomposition.halo import proximity_halo

        p = self.particles
        x = p["x"][: p.n_owned]
        pts = x if around is None else x[around]
        if len(pts):
            lo, hi = pts.min(axis=0), pts.max(axis=0)
        else:
            lo, hi = np.full(self.dim, np.inf), np.full(self.dim, -np.inf)
        halo = proximity_halo(self.comm, x, select, radius or self.radius, lo, hi, self.box)
        return halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))
