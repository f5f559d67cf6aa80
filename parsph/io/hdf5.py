"""Particle frames in one HDF5 file, written collectively with parallel HDF5.

Layout of ``particles.h5``::

    /                      attrs: dim, parsph_version, + the writer's attrs (scene, ...)
    /frames/NNNNNN         attrs: time (s, float64), step (int64); NNNNNN = step, 6 digits
        id        (N,)      int64    global particle id, stable for a particle's life
        x         (N, dim)  float64  position (m)
        v         (N, dim)  float64  velocity (m/s)
        phase     (N,)      uint8    0 solid, 1 fluid, 2 wall
        eps_p     (N,)      float64  accumulated plastic strain (-)
        p         (N,)      float64  pressure (Pa); solid: mean stress
        porosity  (N,)      float64  (-)
        rank      (N,)      int32    rank that owned the row when it was written
        <extra>   (N, ...)           any further field handed to ``write_frame``

In 2D, each vector and tensor field also gets a 3-component view for ParaView, which
reads vectors of 3 and tensors of 9 components only::

    /frames/NNNNNN/xdmf/v   (N, 3)    HDF5 virtual dataset: columns 0, 1 map ``v``,
                                      column 2 is the fill value 0 (no data copied)
    /frames/NNNNNN/xdmf/<f> (N, 3, 3) the same for an (N, 2, 2) field

The views hold no data of their own; :func:`read_frame` skips them and
``particles.xdmf`` points at them (:mod:`parsph.io.xdmf`). ParaView's Xdmf3 reader makes
the vertex cells it draws only from an explicit connectivity, so the file also holds,
once per distinct particle count N, ``/xdmf/vertices_N`` = 0 … N − 1 (int32), shared by
the frames of that count.

N is the global number of owned particles at that step. Rank r writes its owned rows at
rows ``offset … offset + n_r − 1`` where ``offset`` comes from
:func:`decomposition.numbering.global_offset`, so rows are ordered by rank, then by local
order; a reader that wants a particle follows ``id``, never the row number.

Every frame is flushed to disk when written: a run killed later keeps its earlier frames.
The reader helpers (:func:`read_frames`, :func:`read_frame`, :func:`read_attrs`) open
the file with HDF5's default (serial) driver and work on any rank or outside MPI.
"""
from __future__ import annotations

import os
import zlib
from dataclasses import dataclass, field

import numpy as np

import parsph  # noqa: F401 - sets H5PY_ALWAYS_USE_MPI before h5py is imported
import h5py  # noqa: E402
from h5py import h5fd, h5p, h5s  # noqa: E402

from decomposition.comm import raise_if_any
from decomposition.numbering import global_offset
from parsph.errors import ParsphError

FILE_NAME = "particles.h5"
#: Subgroup of a frame holding the 3-component views of its 2D vector and tensor fields.
VIEWS = "xdmf"
#: Root datasets ``xdmf/vertices_N``: the polyvertex connectivity 0 … N − 1 of N particles.
VERTICES = "xdmf/vertices"

#: Required datasets of every frame: name -> (dtype, trailing shape; "dim" = (dim,)).
SCHEMA: dict[str, tuple[np.dtype, str]] = {
    "id": (np.dtype(np.int64), "scalar"),
    "x": (np.dtype(np.float64), "dim"),
    "v": (np.dtype(np.float64), "dim"),
    "phase": (np.dtype(np.uint8), "scalar"),
    "eps_p": (np.dtype(np.float64), "scalar"),
    "p": (np.dtype(np.float64), "scalar"),
    "porosity": (np.dtype(np.float64), "scalar"),
    "rank": (np.dtype(np.int32), "scalar"),
}

PHASE_SOLID, PHASE_FLUID, PHASE_WALL = 0, 1, 2


def frame_name(step: int) -> str:
    """Group path of a frame: ``frames/NNNNNN`` (step zero-padded to 6 digits)."""
    return f"frames/{int(step):06d}"


def resolve_path(path) -> str:
    """``path`` itself, or ``path/particles.h5`` when ``path`` is a directory."""
    path = os.fspath(path)
    if os.path.isdir(path):
        return os.path.join(path, FILE_NAME)
    return path


@dataclass
class FrameInfo:
    """What one frame holds, without its data (enough to describe it in XDMF).

    Attributes
    ----------
    step : int
        Step number.
    time : float
        Simulated time (s).
    n : int
        Global number of rows.
    fields : dict
        Dataset name -> ``(dtype, shape)`` with the global shape.
    views : dict
        Field name -> ``(dtype, shape)`` of its 3-component view ``xdmf/<name>`` (2D
        vector and tensor fields; empty in 3D).
    vertices : tuple or None
        ``(dataset path, dtype)`` of the frame's polyvertex connectivity
        (``xdmf/vertices_N``), None if the file has none (written before it existed).
    """

    step: int
    time: float
    n: int
    fields: dict[str, tuple[np.dtype, tuple[int, ...]]] = field(default_factory=dict)
    views: dict[str, tuple[np.dtype, tuple[int, ...]]] = field(default_factory=dict)
    vertices: tuple[str, np.dtype] | None = None


def _attr_value(key, value):
    """A value h5py can store as an attribute, or a TypeError naming the key."""
    if isinstance(value, (str, bytes, bool, int, float, np.generic)):
        return value
    arr = np.asarray(value)
    if arr.dtype.kind in "biuf" or arr.dtype.kind == "U":
        return arr
    raise TypeError(
        f"file attribute {key!r} has a value of type {type(value).__name__} that HDF5 "
        "cannot store; pass a number, a string or a list of numbers"
    )


class FrameWriter:
    """Collective writer of ``particles.h5``.

    Parameters
    ----------
    path : str or os.PathLike
        The HDF5 file to write, or a directory (then ``path/particles.h5``). The
        directory must exist and be shared by all ranks.
    comm : mpi4py communicator
        Every rank of ``comm`` must create the writer and call :meth:`write_frame` and
        :meth:`close` together (they are collective).
    dim : int
        Spatial dimension, 2 or 3 (shapes of ``x`` and ``v``).
    attrs : dict, optional
        Extra root attributes (scene name, ``particle_size`` in m, ...); numbers,
        strings or lists of numbers, identical on every rank.
    mode : {"w", "a"}
        ``"w"`` creates or truncates the file; ``"a"`` appends to an existing file (a
        restart), in which case a frame written again at an existing step replaces it.
    on_frame : callable, optional
        Called on rank 0 after each frame as ``on_frame(h5_path, frames)`` with the
        index of the frames written so far (:class:`FrameInfo`), e.g. to rewrite an XDMF
        file (:func:`parsph.io.xdmf.xdmf_writer`) so that a run cut short can be opened in
        ParaView; an exception it raises is raised on every rank.

    Notes
    -----
    With an h5py that lacks MPI support the writer works on one rank only (serial
    driver); on more ranks it raises :class:`~parsph.errors.ParsphError`.
    """

    def __init__(self, path, comm, dim: int, attrs: dict | None = None, mode: str = "w",
                 on_frame=None):
        self.path = resolve_path(path)
        self.comm = comm
        self.dim = int(dim)
        self.on_frame = on_frame
        self.frames: list[FrameInfo] = []
        self._file = None
        error = None
        try:
            if self.dim not in (2, 3):
                raise ParsphError(f"FrameWriter: dim must be 2 or 3, got {dim!r}")
            if mode not in ("w", "a"):
                raise ParsphError(f"FrameWriter: mode must be 'w' or 'a', got {mode!r}")
            parent = os.path.dirname(os.path.abspath(self.path))
            if not os.path.isdir(parent):
                raise ParsphError(
                    f"output directory {parent} does not exist; create it (or pass --out "
                    f"to a writable directory) before writing {FILE_NAME}"
                )
            if mode == "a" and not os.path.isfile(self.path):
                raise ParsphError(
                    f"cannot append to {self.path}: no such file; start a new run (mode 'w') "
                    "or point to the directory of the run being restarted"
                )
            self._parallel = bool(h5py.get_config().mpi)
            if not self._parallel and comm.size > 1:
                raise ParsphError(
                    f"h5py {h5py.version.version} was built without MPI, so {self.path} cannot "
                    "be written from several ranks; install parallel h5py (Debian: "
                    "python3-h5py-mpi) and set H5PY_ALWAYS_USE_MPI=1 before importing h5py"
                )
            root_attrs = {"dim": self.dim, "parsph_version": parsph.__version__}
            for key, value in (attrs or {}).items():
                root_attrs[str(key)] = _attr_value(key, value)
        except Exception as exc:  # noqa: BLE001 - agreed on by every rank below
            error = exc
        raise_if_any(comm, error)

        error = None
        try:
            if self._parallel:
                self._file = h5py.File(self.path, mode, driver="mpio", comm=comm)
            else:
                self._file = h5py.File(self.path, mode)
        except OSError as exc:
            error = ParsphError(f"cannot open {self.path} for writing ({exc}); check the "
                                "path and its permissions, and that no other program holds it")
        raise_if_any(comm, error)

        f = self._file
        if mode == "a":
            old_dim = f.attrs.get("dim")
            if old_dim is not None and int(old_dim) != self.dim:
                self._file.close()
                raise ParsphError(f"{self.path} holds dim={int(old_dim)} frames; cannot "
                                  f"append dim={self.dim} frames; write to a new directory")
            self.frames = _index(f)
        for key, value in root_attrs.items():
            f.attrs[key] = value
        f.require_group("frames")
        f.flush()
        if self._parallel:
            self._dxpl = h5p.create(h5p.DATASET_XFER)
            self._dxpl.set_dxpl_mpio(h5fd.MPIO_COLLECTIVE)
        else:
            self._dxpl = None

    # -- context manager -------------------------------------------------------------
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        """Collective: flush and close the file (a second call does nothing)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    # -- writing ---------------------------------------------------------------------
    def drop_frames_after(self, step: int) -> None:
        """Collective: delete the frames after ``step`` (those a run killed after its last
        checkpoint left behind, before a restart from that checkpoint writes its own)."""
        later = [fr.step for fr in self.frames if fr.step > int(step)]
        for s in later:
            del self._file[frame_name(s)]
        if later:
            self._file.flush()
            self.frames = [fr for fr in self.frames if fr.step <= int(step)]

    def _prepare(self, fields: dict) -> tuple[int, dict[str, np.ndarray]]:
        """Local checks and casts: (n_local, {name: C-contiguous array}) in schema order."""
        if not isinstance(fields, dict):
            raise ParsphError(f"write_frame: fields must be a dict of arrays, got {type(fields).__name__}")
        arrays = {str(k): np.asarray(v) for k, v in fields.items()}
        lengths = {k: (a.shape[0] if a.ndim else None) for k, a in arrays.items()}
        scalar = [k for k, n in lengths.items() if n is None]
        if scalar:
            raise ParsphError(f"write_frame: fields {scalar} are scalars; every field needs "
                              "one row per owned particle (first axis)")
        # Rows of a rank with nothing owned may come as any empty shape.
        counts = {k: n for k, n in lengths.items() if arrays[k].size or n}
        distinct = set(counts.values())
        if len(distinct) > 1:
            raise ParsphError(f"write_frame on rank {self.comm.rank}: fields have different "
                              f"numbers of rows {counts}; pass the owned rows only ([:n_owned])")
        n = distinct.pop() if distinct else 0
        out: dict[str, np.ndarray] = {}
        for name, (dtype, kind) in SCHEMA.items():
            trail = (self.dim,) if kind == "dim" else ()
            if name not in arrays:
                if name == "rank":
                    out[name] = np.full(n, self.comm.rank, dtype=dtype)
                else:
                    out[name] = np.zeros((n,) + trail, dtype=dtype)
                continue
            a = arrays[name]
            if a.size == 0 and n == 0:
                a = a.reshape((0,) + trail)
            if a.shape != (n,) + trail:
                raise ParsphError(f"write_frame: field {name!r} has shape {a.shape}, expected "
                                  f"{(n,) + trail} (dim={self.dim})")
            if a.dtype.kind not in "biuf" or (dtype.kind in "iu" and a.dtype.kind == "f"):
                raise ParsphError(f"write_frame: field {name!r} has dtype {a.dtype}; expected "
                                  f"{dtype} (or a type that converts to it without loss)")
            out[name] = np.ascontiguousarray(a, dtype=dtype)
        for name in sorted(set(arrays) - set(SCHEMA)):
            a = arrays[name]
            if a.dtype.kind == "b":
                a = a.astype(np.uint8)
            if a.dtype.kind not in "iuf":
                raise ParsphError(f"write_frame: extra field {name!r} has dtype {a.dtype}; only "
                                  "integer, float and bool fields can be written")
            if name.startswith("/") or "/" in name or not name:
                raise ParsphError(f"write_frame: field name {name!r} is not a plain dataset name")
            out[name] = np.ascontiguousarray(a)
        return n, out

    def _signature(self, step, time, arrays) -> int:
        """A 31-bit hash of what every rank must agree on (names, dtypes, shapes, step, time)."""
        extras = [(k, a.dtype.str, a.shape[1:]) for k, a in arrays.items() if k not in SCHEMA]
        text = repr((int(step), float(time).hex(), extras))
        return zlib.crc32(text.encode()) & 0x7FFFFFFF

    def write_frame(self, step: int, time: float, fields: dict) -> None:
        """Collective: write one frame ``/frames/NNNNNN``.

        Parameters
        ----------
        step : int
            Step number (0 ≤ step ≤ 999999 keeps the 6-digit names sortable).
        time : float
            Simulated time (s), the same on every rank.
        fields : dict of str to ndarray
            This rank's owned rows (first axis = particle). Required fields (see module
            docstring) that are missing are written as zeros, ``rank`` as this rank;
            other fields (e.g. ``rho`` in kg/m³) are written as given. Every rank must
            pass the same extra field names with the same dtype and trailing shape; a
            rank that owns nothing passes empty arrays (or only what it has) and still
            calls this method.

        Raises
        ------
        ParsphError
            On every rank, if any rank's fields are malformed or the ranks disagree.
        """
        if self._file is None:
            raise ParsphError(f"write_frame: {self.path} is closed; create a new FrameWriter")
        error, n, arrays = None, 0, {}
        try:
            if int(step) < 0:
                raise ParsphError(f"write_frame: step must be ≥ 0, got {step}")
            n, arrays = self._prepare(fields)
        except Exception as exc:  # noqa: BLE001 - agreed on by every rank below
            error = exc
        raise_if_any(self.comm, error)

        # Agreement on the schema without a direct collective: the sum of every rank's
        # hash equals size × own hash on all ranks only when all hashes are equal.
        sig = self._signature(step, time, arrays)
        _, total_sig = global_offset(self.comm, sig)
        error = None
        if total_sig != self.comm.size * sig:
            error = ParsphError(
                f"write_frame (step {step}): ranks disagree on the time, the step or the extra "
                f"fields (this rank: {sorted(k for k in arrays if k not in SCHEMA)}); pass the "
                "same extra field names, dtypes and trailing shapes on every rank, also on a "
                "rank that owns no particle"
            )
        raise_if_any(self.comm, error)

        offset, total = global_offset(self.comm, n)
        f = self._file
        name = frame_name(step)
        if name in f:
            del f[name]
        grp = f.create_group(name)
        grp.attrs["time"] = np.float64(time)
        grp.attrs["step"] = np.int64(step)
        info = FrameInfo(step=int(step), time=float(time), n=int(total))
        for key, a in arrays.items():
            shape = (total,) + a.shape[1:]
            dset = grp.create_dataset(key, shape=shape, dtype=a.dtype)
            info.fields[key] = (a.dtype, shape)
            if total > 0:
                self._write_rows(dset, a, offset, n)
        if self.dim == 2 and total > 0:
            for key, (dtype, shape) in info.fields.items():
                if shape[1:] in ((2,), (2, 2)):
                    info.views[key] = _write_view(grp, key, dtype, shape)
        if total > 0:
            info.vertices = self._vertices(total, offset, n)
        f.flush()
        self.frames = [fr for fr in self.frames if fr.step != info.step] + [info]
        self.frames.sort(key=lambda fr: fr.step)
        if self.on_frame is not None:
            error = None
            if self.comm.rank == 0:
                try:
                    self.on_frame(self.path, self.frames)
                except Exception as exc:  # noqa: BLE001 - agreed on by every rank below
                    error = exc
            raise_if_any(self.comm, error)

    def _vertices(self, total: int, offset: int, n: int) -> tuple[str, np.dtype]:
        """Collective: ``xdmf/vertices_<total>`` (0 … total − 1), written if not there."""
        name = f"{VERTICES}_{total}"
        dtype = np.dtype(np.int32 if total < 2**31 else np.int64)
        if name in self._file:
            return name, self._file[name].dtype
        dset = self._file.create_dataset(name, shape=(total,), dtype=dtype)
        self._write_rows(dset, np.arange(offset, offset + n, dtype=dtype), offset, n)
        return name, dtype

    def _write_rows(self, dset, a: np.ndarray, offset: int, n: int) -> None:
        """Collective write of rows ``offset … offset + n − 1`` (n may be 0)."""
        if not self._parallel:
            dset[offset:offset + n] = a
            return
        # h5py's dset[...] = ... returns early on an empty selection, which would leave
        # the other ranks waiting in the collective H5Dwrite; use the low-level call,
        # which takes part with an empty (select_none) selection.
        fspace = dset.id.get_space()
        if n > 0:
            start = (offset,) + (0,) * (a.ndim - 1)
            fspace.select_hyperslab(start, a.shape)
            mspace = h5s.create_simple(a.shape)
        else:
            fspace.select_none()
            mspace = h5s.create_simple((1,) + a.shape[1:])
            mspace.select_none()
            a = np.zeros((1,) + a.shape[1:], dtype=a.dtype)
        dset.id.write(mspace, fspace, a, dxpl=self._dxpl)


def _write_view(grp, name: str, dtype, shape) -> tuple[np.dtype, tuple[int, ...]]:
    """Collective (metadata only): the 3-component view ``grp/xdmf/name`` of a 2D field.

    An HDF5 virtual dataset of shape (N, 3) (or (N, 3, 3)) whose first 2 (2 x 2) entries
    map the dataset ``grp/name`` of shape (N, 2) (or (N, 2, 2)) and whose others read as
    the fill value 0. The source file is named ``"."`` (this file), so the view survives
    moving or renaming the file. Returns the view's ``(dtype, shape)``.
    """
    padded = (shape[0],) + (3,) * (len(shape) - 1)
    layout = h5py.VirtualLayout(shape=padded, dtype=dtype)
    source = h5py.VirtualSource(".", f"{grp.name}/{name}", shape=shape, dtype=dtype)
    layout[(slice(None),) + (slice(0, 2),) * (len(shape) - 1)] = source
    grp.require_group(VIEWS).create_virtual_dataset(name, layout, fillvalue=0)
    return np.dtype(dtype), padded


# -- reading (serial, any rank) --------------------------------------------------------

def _index(f) -> list[FrameInfo]:
    """Frame index of an open file, sorted by step."""
    frames = []
    grp = f.get("frames")
    if grp is None:
        return frames
    for key in grp:
        g = grp[key]
        if not isinstance(g, h5py.Group):
            continue
        step = int(g.attrs.get("step", int(key)))
        info = FrameInfo(step=step, time=float(g.attrs.get("time", np.nan)), n=0)
        for name, d in g.items():
            if isinstance(d, h5py.Dataset):
                info.fields[name] = (d.dtype, tuple(d.shape))
        views = g.get(VIEWS)
        if isinstance(views, h5py.Group):
            for name, d in views.items():
                if isinstance(d, h5py.Dataset) and name in info.fields:
                    info.views[name] = (d.dtype, tuple(d.shape))
        if "id" in info.fields:
            info.n = info.fields["id"][1][0]
        elif info.fields:
            info.n = next(iter(info.fields.values()))[1][0]
        vertices = f.get(f"{VERTICES}_{info.n}")
        if isinstance(vertices, h5py.Dataset) and vertices.shape == (info.n,):
            info.vertices = (vertices.name.lstrip("/"), vertices.dtype)
        frames.append(info)
    frames.sort(key=lambda fr: fr.step)
    return frames


def open_run(path):
    """Open a run's ``particles.h5`` read-only with the serial driver.

    Parameters
    ----------
    path : str or os.PathLike
        The HDF5 file or the run directory holding ``particles.h5``.

    Returns
    -------
    h5py.File

    Raises
    ------
    ParsphError
        If the file is missing, is not HDF5 or holds no ``/frames`` group.
    """
    fname = resolve_path(path)
    if not os.path.isfile(fname):
        raise ParsphError(f"{fname}: no such file; give a run directory written by "
                          f"`parsph run --out DIR` (it holds {FILE_NAME}) or the file itself")
    if not h5py.is_hdf5(fname):
        raise ParsphError(f"{fname} is not an HDF5 file; give the {FILE_NAME} of a parsph "
                          "run (or its directory)")
    try:
        f = h5py.File(fname, "r")
    except OSError as exc:
        raise ParsphError(f"cannot open {fname} ({exc}); if a run is still writing it, wait "
                          "for the next frame or copy the file first") from None
    if "frames" not in f:
        f.close()
        raise ParsphError(f"{fname} holds no /frames group: it is not a parsph particles "
                          "file, or the run stopped before its first frame")
    return f


def read_attrs(path) -> dict:
    """Root attributes of a particles file (``dim``, ``parsph_version``, scene attrs)."""
    with open_run(path) as f:
        return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}


def read_frames(path) -> list[tuple[int, float]]:
    """Steps and times of every frame, sorted by step.

    Parameters
    ----------
    path : str or os.PathLike
        ``particles.h5`` or its run directory.

    Returns
    -------
    list of (int, float)
        ``(step, time)`` pairs; time in s.
    """
    with open_run(path) as f:
        return [(fr.step, fr.time) for fr in _index(f)]


def _pick(fname, frames: list[FrameInfo], step) -> FrameInfo:
    if not frames:
        raise ParsphError(f"{fname} holds no frame yet; wait for the run's first output "
                          "(output.every) or check that the run started")
    if step is None or (isinstance(step, str) and step == "last"):
        return frames[-1]
    if isinstance(step, str):
        raise ParsphError(f"frame selector {step!r} is not understood; use 'last' or a step number")
    for fr in frames:
        if fr.step == int(step):
            return fr
    steps = [fr.step for fr in frames]
    raise ParsphError(f"{fname} has no frame at step {step}; it holds {len(steps)} frames, "
                      f"steps {steps[0]}…{steps[-1]} (see read_frames)")


def read_frame(path, step=None) -> dict[str, np.ndarray]:
    """All datasets of one frame.

    Parameters
    ----------
    path : str or os.PathLike
        ``particles.h5`` or its run directory.
    step : int, "last" or None
        Step to read; None or "last" read the last frame.

    Returns
    -------
    dict of str to ndarray
        Dataset name -> array (rows ordered by writing rank, not by id).
    """
    with open_run(path) as f:
        fr = _pick(f.filename, _index(f), step)
        grp = f[frame_name(fr.step)]
        return {k: d[()] for k, d in grp.items() if isinstance(d, h5py.Dataset)}
