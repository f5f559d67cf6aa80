"""The solid's own view of a coupled scene: reference halo and lists (docs/coupling.md).

In the mixed layout the main particle set holds every row, distributed by reference
position for solids and by current position for the rest, with a current-configuration
halo. TLSPH needs its fixed reference neighbourhoods (section 3): the owned solid rows
are copied into a :class:`SolidView`, which has its own reference halo (an RCB halo in
X), CSR lists built once from X, and a :class:`SolidContext` the unchanged TLSPH stage
runs on. The view is rebuilt when particles leave the solid (phase change), which is
how the reference lists and halos are edited on every rank concerned.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decomposition.halo import Halo
from parsph.scene.materials import PHASE_SOLID
from parsph.core.neighbours import build_csr
from parsph.core.particles import ParticleSet
from parsph.core.context import Context


#: TLSPH work fields kept in the view only, not in the main set: the kernel-gradient
#: correction matrices of eqs. (13)-(14), rebuilt with the view, and the stress term of
#: eq. (13) each step recomputes. In the
#: main set they would cost 144 bytes per particle of every phase (docs/coupling.md).
VIEW_FIELDS = {"L": (3, 3), "Q": (3, 3)}


@dataclass
class SolidContext(Context):
    """The context TLSPH sees in a coupled scene; walls are looked up in ``main``."""

    main: Context = None

    @property
    def wall_set(self):
        """The main set: the walls stay there (a solid moves less than d in a coupled
        step, its speed bounding the step, so a lookup serves several steps)."""
        return self.main.particles


class SolidView:
    """Owned solid rows of ``ctx`` (the main context) with their reference halo; the
    fields named in ``main_only`` stay in the main set.

    Attributes
    ----------
    ctx : SolidContext
        What the TLSPH stage runs on.
    rows : ndarray of int
        Main-set row of each owned solid row (valid after :meth:`locate`).
    """

    def __init__(self, ctx, main_only=()):
        p = ctx.particles
        n = p.n_owned
        self.main = ctx
        rows = np.flatnonzero(p["phase"][:n] == PHASE_SOLID)
        # every field of the main set but ``main_only`` (the fluid's and the coupling's,
        # which TLSPH never reads), and the view's own
        fields = {k: a[:n][rows] for k, a in p.data.items() if k not in main_only}
        fields.update({k: np.zeros((rows.size,) + shape) for k, shape in VIEW_FIELDS.items()})
        sp = ParticleSet(ctx.dim, fields)
        halo = Halo.build(ctx.comm, ctx.rcb_ref, sp["X"][: sp.n_owned], ctx.radius, ctx.box)
        sp.set_halo(halo.exchange(sp.owned_fields(), shift_fields=("x", "X")))
        indptr, indices = build_csr(sp["X"], sp.n_owned, ctx.radius)
        self.ctx = SolidContext(
            scene=ctx.scene, comm=ctx.comm, particles=sp, box=ctx.box, dim=ctx.dim, d=ctx.d,
            h=ctx.h, radius=ctx.radius, rcb=ctx.rcb_ref, halo=halo, indptr=indptr,
            indices=indices, layout="reference", key="X", restarted=ctx.restarted, out=ctx.out,
            materials=ctx.materials, time=ctx.time, step=ctx.step, main=ctx)
        self.ids = sp["id"][: sp.n_owned].copy()
        self.rows = rows

    @property
    def n(self) -> int:
        return self.ctx.particles.n_owned

    def locate(self) -> None:
        """Main-set rows of the solid rows after the main set was re-distributed.

        Solid rows never change rank (their owner follows X), but migration reorders
        the main set; the rows are found again by global id.
        """
        p = self.main.particles
        ids = p["id"][: p.n_owned]
        order = np.argsort(ids, kind="stable")
        pos = np.searchsorted(ids[order], self.ids)
        pos = np.minimum(pos, max(len(order) - 1, 0))
        rows = order[pos] if len(order) else np.zeros(0, dtype=np.int64)
        if len(rows) != len(self.ids) or not np.array_equal(ids[rows], self.ids):
            raise RuntimeError("coupled layout: a solid row left its rank; solid rows are "
                               "owned by their reference position and must not migrate")
        self.rows = rows

    def sync(self, names) -> None:
        """Copy the named fields of the owned solid rows: main set -> view."""
        sp, p = self.ctx.particles, self.main.particles
        for k in names:
            sp[k][: self.n] = p[k][self.rows]

    def write_back(self, names) -> None:
        """Copy the named fields of the owned solid rows: view -> main set."""
        sp, p = self.ctx.particles, self.main.particles
        for k in names:
            p[k][self.rows] = sp[k][: self.n]
