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
from parsph.core.neighbours import build_csr, without_rows
from parsph.core.particles import ParticleSet
from parsph.core.context import Context


#: TLSPH work fields kept in the view only, not in the main set: the kernel-gradient
#: correction matrices of eqs. (13)-(14), rebuilt with the view, and the stress term of
#: eq. (13) each step recomputes. In the
#: main set they would cost 144 bytes per particle of every phase (docs/coupling.md).
VIEW_FIELDS = {"L": (3, 3), "Q": (3, 3)}


@dataclass
class ViewEdit:
    """What a view edited after a phase change (:meth:`SolidView.without_fluidised`)
    keeps of the last one: which of the last view's owned rows stay (``keep``), their
    main-set rows (``rows``), the edited reference halo and lists; for the solid's
    set-up (:meth:`parsph.solid.stage.TLSPH.setup`) which of the list entries stay
    (``entry``), the new rows that lost a neighbour (``lost``: the only correction
    matrices that change) and the correction matrices of the rows that stay (``L``)."""

    keep: np.ndarray
    rows: np.ndarray
    halo: Halo
    indptr: np.ndarray
    indices: np.ndarray
    entry: np.ndarray
    lost: np.ndarray
    L: np.ndarray


@dataclass
class SolidContext(Context):
    """The context TLSPH sees in a coupled scene; walls are looked up in ``main``."""

    main: Context = None

    @property
    def wall_set(self):
        """The main set: the walls stay there (a solid moves less than d in a coupled
        step, its speed bounding the step, so a lookup serves several steps)."""
        return self.main.particles

    def add_work(self, body: float, constraint: float = 0.0, hourglass: float = 0.0) -> None:
        """The solid's work goes to the main context's step total."""
        self.main.add_work(body, constraint, hourglass)


class SolidView:
    """Owned solid rows of ``ctx`` (the main context) with their reference halo; the
    fields named in ``main_only`` stay in the main set.

    Attributes
    ----------
    ctx : SolidContext
        What the TLSPH stage runs on.
    rows : ndarray of int
        Main-set row of each owned solid row (valid after :meth:`locate`).
    edit : ViewEdit or None
        What this view kept of the last one, if it is that one edited.
    """

    def __init__(self, ctx, main_only=(), carried=(), carry=None, edit=None):
        p = ctx.particles
        n = p.n_owned
        self.main = ctx
        self.edit = edit  # (ViewEdit: this view is ``carry`` edited, see without_fluidised)
        rows = np.flatnonzero(p["phase"][:n] == PHASE_SOLID) if edit is None else edit.rows
        # every field of the main set but ``main_only`` (the fluid's and the coupling's,
        # which TLSPH never reads), and the view's own
        fields = {k: a[:n][rows] for k, a in p.data.items() if k not in main_only}
        missing = [k for k in carried if k not in fields]
        if missing:  # the state only the last view held: its rows that stay, or by id
            fields.update({k: carry.ctx.particles[k][: carry.n][edit.keep] for k in missing}
                          if edit is not None else _take_over(carry, p["id"][:n][rows], missing))
        fields.update({k: np.zeros((rows.size,) + shape) for k, shape in VIEW_FIELDS.items()})
        sp = ParticleSet(ctx.dim, fields)
        halo = Halo.build(ctx.comm, ctx.rcb_ref, sp["X"][: sp.n_owned], ctx.radius, ctx.box) \
            if edit is None else edit.halo
        sp.set_halo(halo.exchange(sp.owned_fields(), shift_fields=("x", "X")))
        indptr, indices = build_csr(sp["X"], sp.n_owned, ctx.radius) if edit is None \
            else (edit.indptr, edit.indices)
        self.ctx = SolidContext(
            scene=ctx.scene, comm=ctx.comm, particles=sp, box=ctx.box, dim=ctx.dim, d=ctx.d,
            h=ctx.h, radius=ctx.radius, rcb=ctx.rcb_ref, halo=halo, indptr=indptr,
            indices=indices, layout="reference", key="X", restarted=ctx.restarted, out=ctx.out,
            materials=ctx.materials, time=ctx.time, step=ctx.step, main=ctx)
        self.ids = sp["id"][: sp.n_owned].copy()
        self.rows = rows
        self._rows_max = int(rows.max()) if len(rows) else -1

    def without_fluidised(self, main_only=(), carried=()) -> "SolidView":
        """Collective: the view of this one's rows still solid in the main set (those a
        phase change took out left), edited instead of built: its reference halo by
        :meth:`decomposition.halo.Halo.without` and its lists by
        :func:`parsph.core.neighbours.without_rows`, with no geometric search. The rows
        that stay keep their order, in the view and in its halo, so the lists are what
        :func:`build_csr` gives (ascending) and the fields what a new view copies;
        ``edit`` (:class:`ViewEdit`) tells the solid's set-up what it may keep.

        A phase change only takes rows out of the solid, and solid rows never change
        rank, so the main set's solid rows are this view's less those that left;
        RuntimeError if not (build a new view instead)."""
        ctx = self.main
        self.locate()
        p = ctx.particles
        keep = p["phase"][self.rows] == PHASE_SOLID
        if int(keep.sum()) != int((p["phase"][: p.n_owned] == PHASE_SOLID).sum()):
            raise RuntimeError("solid view: the main set has solid rows the last view has "
                               "not; build a new view (SolidView) instead of editing it")
        old = self.ctx.particles
        halo, kept = self.ctx.halo.without(keep)
        renumber = np.full(old.n_total, -1, dtype=self.ctx.indices.dtype)
        renumber[: self.n][keep] = np.arange(int(keep.sum()))
        renumber[self.n:][kept] = int(keep.sum()) + np.arange(int(kept.sum()))
        indptr, indices, entry, lost = without_rows(self.ctx.indptr, self.ctx.indices, keep,
                                                    renumber)
        edit = ViewEdit(keep=keep, rows=self.rows[keep], halo=halo, indptr=indptr,
                        indices=indices, entry=entry, lost=np.flatnonzero(lost),
                        L=old["L"][: self.n][keep])
        return SolidView(ctx, main_only, carried, self, edit)

    def state_to(self, names) -> tuple:
        """Put the named fields of the view back in the main set (owned solid rows; zero
        on the other rows, halo included) where the main set lacks them; returns the
        names put back."""
        p, sp = self.main.particles, self.ctx.particles
        added = tuple(k for k in names if k not in p)
        if added:
            self.locate()
        for k in added:
            a = np.zeros((p.n_total,) + sp[k].shape[1:], dtype=sp[k].dtype)
            a[self.rows] = sp[k][: self.n]
            p.data[k] = a
        return added

    @property
    def n(self) -> int:
        return self.ctx.particles.n_owned

    def locate(self) -> None:
        """Main-set rows of the solid rows after the main set was re-distributed.

        Solid rows never change rank (their owner follows X), but migration reorders
        the main set; the rows are found again by global id. When every row found last
        time still holds its particle (a step without migration: one rank, or no row
        moved) they are kept without the search (two sorts of the owned ids per step).
        """
        p = self.main.particles
        ids = p["id"][: p.n_owned]
        rows = self.rows
        if (len(rows) == len(self.ids) and (len(rows) == 0 or self._rows_max < len(ids))
                and np.array_equal(ids[rows], self.ids)):
            return
        rows = _rows_of(ids, self.ids)
        if rows is None:
            raise RuntimeError("coupled layout: a solid row left its rank; solid rows are "
                               "owned by their reference position and must not migrate")
        self.rows = rows
        self._rows_max = int(rows.max()) if len(rows) else -1

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


def _take_over(old, ids, names) -> dict:
    """The named fields of the owned rows ``ids`` from the view ``old``, which owns all of
    them (a view rebuilt after a phase change owns the last one's solids less the
    fluidised)."""
    if old is None:
        raise RuntimeError(f"solid view: fields {names} are in neither the main set nor a "
                           "last view")
    pos = _rows_of(old.ids, ids)
    if pos is None:
        raise RuntimeError("solid view: a solid row of the new view was not in the last one; "
                           "its state is lost (solid rows must not change rank between views)")
    sp = old.ctx.particles
    return {k: sp[k][: old.n][pos] for k in names}


def _rows_of(ids, wanted):
    """Row of each of the ids ``wanted`` in ``ids`` (distinct), or None if one is
    missing."""
    order = np.argsort(ids, kind="stable")
    rows = order[np.minimum(np.searchsorted(ids[order], wanted), max(len(order) - 1, 0))] \
        if len(order) else np.zeros(0, dtype=np.int64)
    if len(rows) != len(wanted) or not np.array_equal(ids[rows], wanted):
        return None
    return rows
