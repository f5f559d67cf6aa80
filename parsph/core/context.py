"""What the stages of a step see: the particles, the halo and neighbour lists, the
partition, the time, and the collective look-ups of nearby walls."""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from decomposition.box import Box
from decomposition.halo import Halo
from decomposition.partition import RCB
from decomposition.reduce import global_any
from decomposition.box import masked_bounds
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
    #: The ``rcb_ref`` whose owners the solids were last sent to (mixed layout): under
    #: the same cuts they are all home (their X is fixed), so none is looked up again.
    solids_placed: RCB = None
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
    #: With ``wet_lists``: 1 for the owned rows within two cells (at least 2 radii) of a
    #: fluid row when the lists were built (``build_csr``'s ``near``), else None.
    near_fluid: np.ndarray = None
    #: The order of the rows in each current-configuration list (``build_csr``'s
    #: ``visit``), None: ascending index.
    list_order: np.ndarray = None
    #: Fields the current-configuration halo does not carry (their halo rows are zero):
    #: in the mixed layout the solid's state, which only the solid's view reads, on its
    #: own reference halo (docs/performance.md).
    halo_skip: tuple = ()
    #: Set by a stage that holds part of the particles' state outside this set (the
    #: coupled stage's solid view keeps the solid's tensors): ``fields_outside(names=None)``
    #: puts those named (None: all) back in the set and returns the names put back (see
    #: :meth:`all_fields`); ``outside_names`` names them all.
    fields_outside: object = None
    outside_names: tuple = ()
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
    #: (names, lo, hi, rows): the last wall lookup of :meth:`nearby_walls` and its box
    wall_cache: tuple = None
    _g_norm: float = None  # |g|, once (body_acceleration_norm)
    #: This rank's work on its owned rows in the current step (J; J/m in 2D), added by
    #: the stages (:meth:`add_work`): [0] the body force's (gravity and the earthquake),
    #: [1] the Dirichlet constraints', [2] the solid's hourglass control's. The driver
    #: zeroes it before each step and sums it over the ranks in the stats row
    #: (docs/energy.md).
    work: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def at_sync_step(self) -> bool:
        """Whether ``step`` is a sync step (``step % sync_every == 0``)."""
        return self.step % self.sync_every == 0

    @property
    def n_owned(self) -> int:
        return self.particles.n_owned

    @contextmanager
    def all_fields(self, names=None):
        """Every field of the particles' state in the set for the duration (a probe
        sample), or those ``names`` of it: what a stage holds outside the set
        (:attr:`fields_outside`) is put back, and taken out again after. Yields the names
        put back (not those the set had already)."""
        added = self.fields_outside(names) if self.fields_outside is not None else ()
        try:
            yield added
        finally:
            for name in added:
                self.particles.data.pop(name, None)

    def fields_one_at_a_time(self):
        """Yields ``(name, owned rows)`` of each field a stage holds outside the set, each
        in the set for its own turn only: a checkpoint writes the solid's tensors so. All
        at once (:meth:`all_fields`) they had been the peak of a 3D coupled run (240 bytes
        per particle beside the step's own arrays, docs/performance.md)."""
        for name in self.outside_names:
            with self.all_fields((name,)) as added:
                if name in added:
                    yield name, self.particles[name][: self.n_owned]

    def update_halo(self, names) -> None:
        """Refresh the halo rows of the named fields from their owners (same pattern)."""
        p = self.particles
        if self.halo.n_send == 0 and self.halo.n_halo == 0 and p.n_halo == 0:
            return  # nothing moves (one rank, no periodic images): 9 calls had cost 69 us
            # of a 2D coupled step of 1,100 particles (jobs/bench_overhead.py)
        fresh = self.halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))
        for name, rows in fresh.items():
            p[name][p.n_owned:] = rows

    def nearby_walls(self, names, around=None, reach=None) -> dict:
        """Collective: the named fields of every wall row within ``reach`` (default 2h,
        at most 4h) of this rank's particles (``around``: bool mask of owned rows, default
        all; current ``x``), and maybe more, sorted by particle id, so the result does not
        depend on the lookup's history.

        The walls are fixed: one lookup around the particles' bounding box widened by
        2h serves every later call while each rank's particles stay inside that box
        (less ``reach`` - 2h); the test is one logical-or reduction, where a lookup is an
        ``allgather`` and an exchange (of a 2D coupled step of 260 particles, 0.2 of its
        2.4 ms)."""
        p = self.particles
        x = p["x"][: p.n_owned]
        lo, hi = masked_bounds(x, np.ones(len(x), bool) if around is None else around)
        key = tuple(names) + ("id",)
        c = self.wall_cache
        margin = 0.0 if reach is None else reach - self.radius
        stale = c is None or c[0] != key or bool((lo - margin < c[1]).any()
                                                 or (hi + margin > c[2]).any())
        if global_any(self.comm, stale):
            lo, hi = lo - self.radius, hi + self.radius
            rows = self._walls_near(key, lo, hi)
            order = np.argsort(rows["id"], kind="stable")
            self.wall_cache = (key, lo, hi, {k: a[order] for k, a in rows.items()})
        return self.wall_cache[3]

    @property
    def wall_set(self) -> ParticleSet:
        """The particle set whose owned wall rows :meth:`nearby_walls` looks up."""
        return self.particles

    def _walls_near(self, names, lo, hi) -> dict:
        """Collective: the named fields of the wall rows of :attr:`wall_set` within 2h
        of the box [lo, hi]."""
        from decomposition.halo import proximity_halo

        p = self.wall_set
        n = p.n_owned
        halo = proximity_halo(self.comm, p["x"][:n], p["phase"][:n] == PHASE_WALL, self.radius,
                              lo, hi, self.box)
        return halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))

    def add_work(self, body: float, constraint: float = 0.0, hourglass: float = 0.0) -> None:
        """Add a stage's work on this rank's owned rows in this step to :attr:`work`
        (:func:`parsph.core.energy.step_work`)."""
        self.work[0] += body
        self.work[1] += constraint
        self.work[2] += hourglass

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

    def body_acceleration_norm(self, t: float) -> float:
        """|:meth:`body_acceleration` (t)| (m/s²); without a record, |g| computed once."""
        if self.scene.data.get("record") is not None:
            return float(np.linalg.norm(self.body_acceleration(t)))
        if self._g_norm is None:
            self._g_norm = float(np.linalg.norm(self.gravity))
        return self._g_norm

    @property
    def gravity(self) -> np.ndarray:
        return np.asarray(self.scene.gravity.g, dtype=float)
