"""Checkpoints: everything the next step reads, in one HDF5 file, written atomically.

Layout of ``checkpoint.h5``::

    /           attrs: format, parsph_version, scene, scene_physics (hash),
                       scene_physics_keys (a hash per table), dim, ranks, time, step,
                       next_frame, last_frame_step, next_checkpoint
    /counts     (ranks,) int64      owned rows of each rank when written
    /fields/F   (N, ...)            every per-particle field, rows in rank order
    /rcb/...                        the partition (decomposition.partition.RCB arrays)
    /stages/S/K                     scalar state of stage S (its ``state()`` dict)

Notes
-----
Writes are collective with parallel HDF5 (each rank writes its rows independently at
the offset of an exclusive prefix sum) into ``checkpoint.h5.tmp``; rank 0 then renames it
over ``checkpoint.h5`` (atomic on POSIX), so an interrupted write never replaces the last
good checkpoint. On restart at the same rank count each rank reads back exactly its own
rows and the stored partition, and every checkpoint falls on a sync step (where the
uninterrupted run sets its preconditioners up afresh too, :mod:`parsph.step.run`), so the
continued run is bit-for-bit the uninterrupted one. At another rank count the rows are
split evenly and re-partitioned (the result then agrees to round-off and solver
tolerance).
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import os

import numpy as np

import parsph
import h5py  # noqa: E402 - after parsph sets H5PY_ALWAYS_USE_MPI

from decomposition.comm import collective, on_root
from decomposition.numbering import global_offset
from decomposition.partition import RCB
from decomposition.reduce import barrier
from parsph.errors import ParsphError

FORMAT = 1
FILE_NAME = "checkpoint.h5"


#: Scene fields a restart or a branch may change (and the ones that are no settings).
FREE = {"run", "output", "probes", "study", "source", "data"}


def _physics_parts(scene) -> list[tuple[str, str]]:
    return [(f.name, f"{f.name}={getattr(scene, f.name)!r}") for f in dataclasses.fields(scene)
            if f.name not in FREE]


def physics_hash(scene) -> str:
    """A hash of the scene keys a restart must not change (all but ``run``, ``output``,
    ``probes`` and ``study``, which are no physics)."""
    parts = [text for _, text in _physics_parts(scene)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def physics_keys(scene) -> str:
    """``section=hash`` of each table :func:`physics_hash` covers, comma-separated: lets a
    refused restart name the tables that differ."""
    return ",".join(f"{name}={hashlib.sha256(text.encode()).hexdigest()[:12]}"
                    for name, text in _physics_parts(scene))


def _changed_tables(stored: str, scene) -> list[str]:
    """Tables whose hash in ``stored`` (:func:`physics_keys`) differs from ``scene``'s."""
    old = dict(item.split("=", 1) for item in stored.split(",") if "=" in item)
    new = dict(item.split("=", 1) for item in physics_keys(scene).split(","))
    return sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))


def _open(path, mode, comm):
    kwargs = {"driver": "mpio", "comm": comm} if h5py.get_config().mpi else {}
    return h5py.File(path, mode, **kwargs)


def write(path: str, comm, particles, rcb, meta: dict, stage_states: dict, fault=None,
          rcb_ref=None, rcb_wall=None, more=()) -> None:
    """Collective: write a checkpoint atomically (temporary file, then rename).

    Parameters
    ----------
    particles : ParticleSet
        Its owned rows of every field are written.
    more : iterable of (str, numpy.ndarray)
        More fields (owned rows), written one after the other as they come (the state a
        stage holds outside the set, :meth:`Context.fields_one_at_a_time`); every rank
        yields the same names.
    rcb : RCB
        The current partition (mixed layout: of the fluid rows).
    rcb_ref, rcb_wall : RCB, optional
        Mixed layout: the solids' partition (by X) and the walls'.
    meta : dict
        Scalars stored as root attributes (time, step, next_frame, …).
    stage_states : dict of str to dict
        ``{stage name: stage.state()}``; values numbers or arrays.
    fault : callable, optional
        Testing aid: called after the fields are written, before the file is closed.
    """
    tmp = path + ".tmp"
    n = particles.n_owned
    offset, total = global_offset(comm, n)
    counts = np.array(comm.allgather(n), dtype=np.int64)
    with collective(comm):
        f = _open(tmp, "w", comm)
    try:
        f.attrs["format"] = FORMAT
        f.attrs["parsph_version"] = parsph.__version__
        f.attrs["ranks"] = comm.size
        for key, value in meta.items():
            f.attrs[key] = value
        f.create_dataset("counts", data=counts)
        grp = f.create_group("fields")
        for name, arr in itertools.chain(
                ((k, particles[k][:n]) for k in sorted(particles.data)), more):
            dset = grp.create_dataset(name, shape=(total,) + arr.shape[1:], dtype=arr.dtype)
            if n:
                dset[offset:offset + n] = arr
        for name, part in (("rcb", rcb), ("rcb_ref", rcb_ref), ("rcb_wall", rcb_wall)):
            if part is None:
                continue
            rgrp = f.create_group(name)
            for key, value in part.to_arrays().items():
                rgrp.create_dataset(key, data=value)
        sgrp = f.create_group("stages")
        for stage, state in sorted(stage_states.items()):
            g = sgrp.create_group(stage)
            for key, value in sorted(state.items()):
                g.create_dataset(key, data=np.asarray(value))
        if fault is not None:
            fault()
    finally:
        f.close()
    barrier(comm)
    if comm.rank == 0:
        os.replace(tmp, path)
    barrier(comm)


class Checkpoint:
    """What a restart reads: this rank's rows, the partition if reusable, the scalars."""

    def __init__(self, fields, rcb, meta, stage_states):
        self.fields = fields
        self.rcb = rcb
        self.meta = meta
        self.stage_states = stage_states


def _check_header(path: str, scene) -> dict:
    """Rank 0: open the file serially and check it is a checkpoint of this scene."""
    if not os.path.exists(path):
        raise ParsphError(f"restart file '{path}' does not exist; give the checkpoint.h5 of an "
                          f"earlier run of this scene")
    if os.path.isdir(path):
        raise ParsphError(f"restart file '{path}' is a directory; give the checkpoint file in "
                          f"it, e.g. --restart {os.path.join(path, 'checkpoint.h5')}")
    try:
        with h5py.File(path, "r") as f:
            attrs = dict(f.attrs)
            ok = {"counts", "fields", "rcb", "stages"} <= set(f.keys())
            names = set(f["fields"].keys()) if "fields" in f else set()
    except (OSError, KeyError):
        raise ParsphError(f"restart file '{path}' is not a readable HDF5 checkpoint (truncated "
                          f"or corrupt?); use an earlier checkpoint or start from the scene") from None
    if attrs.get("format") != FORMAT or not ok:
        raise ParsphError(f"restart file '{path}' is not a parsph checkpoint (format "
                          f"{attrs.get('format')!r}); give a checkpoint.h5 written by parsph run")
    if attrs.get("scene") != scene.name:
        raise ParsphError(f"restart file '{path}' is from scene '{attrs.get('scene')}', not "
                          f"'{scene.name}'; restart with the scene that wrote it")
    if attrs.get("scene_physics") != physics_hash(scene):
        stored = attrs.get("scene_physics_keys")
        tables = _changed_tables(str(stored), scene) if stored is not None else []
        what = (f"[{'], ['.join(tables)}] differ{'s' if len(tables) == 1 else ''}; "
                if tables else "")
        raise ParsphError(f"restart file '{path}' was written with other scene settings: "
                          f"{what}a restart or a branch (--restart FILE --out DIR) may change "
                          f"only run.*, output.*, study.* and [[probes]] keys (domain, "
                          f"materials, bodies, walls, gravity, solid and fluid must be as "
                          f"before); start a new run to change the others")
    missing = {"id", "x", "v", "m", "phase", "material", "X"} - names
    if missing:
        raise ParsphError(f"restart file '{path}' lacks fields {sorted(missing)}; it is damaged")
    return {k: (v.item() if hasattr(v, "item") else v) for k, v in attrs.items()}


def read(path: str, comm, scene) -> Checkpoint:
    """Collective: validate on rank 0 (one clear error everywhere), then read this rank's rows."""
    meta = on_root(comm, _check_header, path, scene)
    with collective(comm):
        f = _open(path, "r", comm)
    try:
        counts = f["counts"][...]
        same = len(counts) == comm.size
        if same:
            start = int(counts[: comm.rank].sum())
            stop = start + int(counts[comm.rank])
        else:
            total = int(counts.sum())
            start = total * comm.rank // comm.size
            stop = total * (comm.rank + 1) // comm.size
        fields = {name: dset[start:stop] for name, dset in f["fields"].items()}
        rcb = RCB.from_arrays({k: v[...] for k, v in f["rcb"].items()}) if same else None
        rcb_ref, rcb_wall = (RCB.from_arrays({k: v[...] for k, v in f[name].items()})
                             if same and name in f else None for name in ("rcb_ref", "rcb_wall"))
        states = {s: {k: (v[()] if v.shape == () else v[...]) for k, v in g.items()}
                  for s, g in f["stages"].items()}
    finally:
        f.close()
    ck = Checkpoint(fields, rcb, meta, states)
    ck.rcb_ref, ck.rcb_wall = rcb_ref, rcb_wall
    return ck
