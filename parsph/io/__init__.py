"""Output of a run: particle frames (HDF5 + XDMF), per-step statistics (CSV), pictures.

- :class:`~parsph.io.hdf5.FrameWriter`, :func:`~parsph.io.hdf5.read_frames`,
  :func:`~parsph.io.hdf5.read_frame`, :func:`~parsph.io.hdf5.read_attrs`:
  ``particles.h5``, written collectively, read serially.
- :func:`~parsph.io.xdmf.write_xdmf`: ``particles.xdmf`` for ParaView (rank 0 only);
  :func:`~parsph.io.xdmf.xdmf_writer` rewrites it after each frame a ``FrameWriter``
  writes. ``xdmf`` imports ``hdf5``, never the reverse.
- :class:`~parsph.io.stats.StatsWriter`, :func:`~parsph.io.stats.read_stats`:
  ``stats.csv``.
- :class:`~parsph.io.probes.ProbeWriter`, :func:`~parsph.io.probes.read_probes`:
  ``probes.csv`` (and ``probes_points.csv``).
- :func:`~parsph.io.plot.plot_run`: PNG pictures of frames (``parsph plot``).
- :func:`~parsph.io.series.plot_series`: stats.csv and probes.csv over time in one PNG
  (``parsph plot --series``).
- :class:`~parsph.io.frames.FrameReader`: the frames read in parallel, each rank its
  share of the rows (``parsph maps``).
- :mod:`~parsph.io.geotiff`: float32 GeoTIFF rasters, georeferenced, written by every rank
  into its own rows of one file.

Names are imported lazily, so ``import parsph.io`` loads neither h5py nor matplotlib.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "FrameWriter": "parsph.io.hdf5",
    "FrameInfo": "parsph.io.hdf5",
    "SCHEMA": "parsph.io.hdf5",
    "read_frames": "parsph.io.hdf5",
    "read_frame": "parsph.io.hdf5",
    "read_attrs": "parsph.io.hdf5",
    "write_xdmf": "parsph.io.xdmf",
    "xdmf_writer": "parsph.io.xdmf",
    "StatsWriter": "parsph.io.stats",
    "read_stats": "parsph.io.stats",
    "ProbeWriter": "parsph.io.probes",
    "read_probes": "parsph.io.probes",
    "plot_run": "parsph.io.plot",
    "plot_series": "parsph.io.series",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'parsph.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
