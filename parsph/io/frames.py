"""Frames of ``particles.h5`` read in parallel: each rank its share of a frame's rows.

The file is opened by every rank of the communicator, with HDF5's MPI-IO driver when
h5py has MPI support (as :class:`parsph.io.hdf5.FrameWriter` writes it), else with the
serial driver on each rank (read-only opens of one file by several processes are safe).
Rank ``r`` of ``P`` reads the rows ``r N / P … (r + 1) N / P − 1`` of a frame of ``N``
rows, in chunks of at most ``chunk`` rows; every rank goes through the same number of
chunks (some empty), so a caller may run a collective per chunk.
"""
from __future__ import annotations

import math

import numpy as np

import parsph  # noqa: F401 - sets H5PY_ALWAYS_USE_MPI before h5py is imported
import h5py  # noqa: E402

from decomposition.comm import collective
from parsph.errors import ParsphError
from parsph.io.hdf5 import _index, frame_name, resolve_path

#: Rows read at once per rank (a chunk of x, v and phase is 2^20 x 49 B = 51 MB).
CHUNK = 1 << 20


def share(n: int, rank: int, size: int) -> tuple[int, int]:
    """``(start, stop)`` of rank ``rank``'s rows of a frame of ``n`` rows."""
    return rank * n // size, (rank + 1) * n // size


class FrameReader:
    """Collective reader of a run's frames.

    Parameters
    ----------
    path : str or os.PathLike
        ``particles.h5`` or the run directory holding it.
    comm : mpi4py communicator
        Every rank creates the reader, calls :meth:`chunks` for the same frames and
        :meth:`close` (or uses it as a context manager).

    Attributes
    ----------
    frames : list of FrameInfo
        The frames, sorted by step (:func:`parsph.io.hdf5._index`).
    """

    def __init__(self, path, comm, chunk: int = CHUNK):
        self.path = resolve_path(path)
        self.comm = comm
        self.chunk = int(chunk)
        self._file = None
        with collective(comm):
            try:
                if h5py.get_config().mpi:
                    self._file = h5py.File(self.path, "r", driver="mpio", comm=comm)
                else:
                    self._file = h5py.File(self.path, "r")
            except OSError as exc:
                raise ParsphError(f"cannot open {self.path} for reading ({exc}); check that "
                                  "it is a parsph particles file") from None
        self.frames = _index(self._file)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        """Collective: close the file (a second call does nothing)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def has(self, step: int, name: str) -> bool:
        """Whether frame ``step`` holds the dataset ``name``."""
        return name in self._file[frame_name(step)]

    def chunks(self, step: int, names):
        """Yield this rank's rows of frame ``step``, chunk by chunk.

        Parameters
        ----------
        step : int
            The frame's step.
        names : sequence of str
            Datasets to read (each must be in the frame).

        Yields
        ------
        dict of str to ndarray
            ``{name: rows}`` of one chunk (possibly empty); every rank yields the same
            number of chunks, ``ceil(ceil(N / P) / chunk)`` (at least one).
        """
        grp = self._file[frame_name(step)]
        n = int(grp[names[0]].shape[0])
        start, stop = share(n, self.comm.rank, self.comm.size)
        rounds = max(1, math.ceil(math.ceil(n / self.comm.size) / self.chunk))
        for k in range(rounds):
            a = min(start + k * self.chunk, stop)
            b = min(a + self.chunk, stop)
            out = {}
            for name in names:
                dset = grp[name]
                out[name] = dset[a:b] if b > a else np.zeros((0,) + dset.shape[1:], dset.dtype)
            yield out
