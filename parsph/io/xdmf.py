"""XDMF 3 description of ``particles.h5`` so that ParaView (or VisIt) opens a run.

The XDMF file is a temporal collection with one ``Polyvertex`` grid per frame (one
vertex per particle) whose data stay in the HDF5 file, referenced relatively
(``particles.h5:/frames/000010/x``), so the run directory can be moved as a whole.

Field mapping
-------------
ParaView (5.11, both its Xdmf3 readers and the older XDMF reader) takes a Vector
attribute of 3 components and a Tensor of 9 only, and it cannot read computed items
(``HyperSlab`` or ``Function``/``JOIN`` data items: "Skipping unrecognized array type
[None]"). Every attribute therefore points at a plain HDF5 dataset:

- Geometry: dataset ``x``; ``GeometryType="XY"`` in 2D, ``"XYZ"`` in 3D (ParaView puts
  z = 0 in 2D; ``x`` is not repeated as an attribute).
- A field with one value per particle (``eps_p``, ``p``, ``phase``, ``id``, ...) is a
  ``Scalar`` attribute.
- A field of shape (N, dim) (``v``) is a ``Vector`` attribute and (N, dim, dim) a
  ``Tensor``: in 3D the dataset itself, in 2D its 3-component view ``xdmf/<name>``
  written by :class:`~parsph.io.hdf5.FrameWriter` (an HDF5 virtual dataset: the 2
  components of the field and z = 0, no data copied).
- Any other shape ((N, 4), or a 2D field of a file written before the views) is a
  ``Matrix`` attribute: an array of as many components as a row holds.

The ``Polyvertex`` topology of a frame of N particles points at ``xdmf/vertices_N``
(0 … N − 1): ParaView's Xdmf3 readers build the vertex cells they draw only from an
explicit connectivity (without it the points are there but nothing is drawn).

Frames with no particle are left out (a grid of zero points stops some readers).
"""
from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET

import numpy as np

from parsph.errors import ParsphError
from parsph.io.hdf5 import VIEWS, FrameInfo, _index, frame_name, open_run, resolve_path


def _number_type(dtype: np.dtype) -> tuple[str, str]:
    """XDMF ``NumberType`` and ``Precision`` of a numpy dtype."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return "Float", str(dtype.itemsize)
    if dtype.kind == "i":
        return ("Char" if dtype.itemsize == 1 else "Int"), str(dtype.itemsize)
    if dtype.kind in "ub":
        return ("UChar" if dtype.itemsize == 1 else "UInt"), str(dtype.itemsize)
    raise ParsphError(f"XDMF cannot describe a dataset of dtype {dtype}")


def _dims(shape) -> str:
    return " ".join(str(int(s)) for s in shape)


def _hdf_item(parent, ref: str, dtype, shape):
    ntype, prec = _number_type(dtype)
    item = ET.SubElement(parent, "DataItem", {
        "Dimensions": _dims(shape), "NumberType": ntype, "Precision": prec, "Format": "HDF",
    })
    item.text = ref
    return item


def _attribute(grid, name: str, kind: str, ref: str, dtype, shape) -> None:
    attr = ET.SubElement(grid, "Attribute", {"Name": name, "AttributeType": kind, "Center": "Node"})
    _hdf_item(attr, ref, dtype, shape)


def attribute_kind(trail: tuple) -> str:
    """XDMF ``AttributeType`` of a field whose rows have shape ``trail`` (2D vectors and
    tensors already padded to 3 components by their view)."""
    if int(np.prod(trail, dtype=np.int64)) == 1:
        return "Scalar"
    if trail == (3,):
        return "Vector"
    if trail == (3, 3):
        return "Tensor"
    return "Matrix"


def build_xdmf(frames: list[FrameInfo], h5_ref: str, dim: int) -> ET.Element:
    """The XDMF tree for a frame index.

    Parameters
    ----------
    frames : list of FrameInfo
        Frames to describe (steps, times, dataset shapes and dtypes).
    h5_ref : str
        Path of the HDF5 file as seen from the XDMF file's directory.
    dim : int
        Spatial dimension, 2 or 3.

    Returns
    -------
    xml.etree.ElementTree.Element
        The ``Xdmf`` root element.
    """
    root = ET.Element("Xdmf", {"Version": "3.0", "xmlns:xi": "http://www.w3.org/2001/XInclude"})
    domain = ET.SubElement(root, "Domain")
    series = ET.SubElement(domain, "Grid", {
        "Name": "particles", "GridType": "Collection", "CollectionType": "Temporal",
    })
    for fr in frames:
        if fr.n == 0 or "x" not in fr.fields:
            continue
        group = frame_name(fr.step)
        grid = ET.SubElement(series, "Grid", {"Name": f"step_{fr.step:06d}", "GridType": "Uniform"})
        ET.SubElement(grid, "Time", {"Value": repr(float(fr.time))})
        topology = ET.SubElement(grid, "Topology", {
            "TopologyType": "Polyvertex", "NumberOfElements": str(fr.n), "NodesPerElement": "1",
        })
        if fr.vertices is not None:  # without it, the Xdmf3 readers make no cell to draw
            path, vdtype = fr.vertices
            _hdf_item(topology, f"{h5_ref}:/{path}", vdtype, (fr.n,))
        geometry = ET.SubElement(grid, "Geometry", {"GeometryType": "XY" if dim == 2 else "XYZ"})
        xdtype, xshape = fr.fields["x"]
        _hdf_item(geometry, f"{h5_ref}:/{group}/x", xdtype, xshape)
        for name in sorted(fr.fields):
            dtype, shape = fr.fields[name]
            if name == "x" or shape[0] != fr.n:
                continue  # the geometry itself, or not a per-particle field
            ref = f"{h5_ref}:/{group}/{name}"
            if name in fr.views:  # 2D vector or tensor: its 3-component view
                dtype, shape = fr.views[name]
                ref = f"{h5_ref}:/{group}/{VIEWS}/{name}"
            _attribute(grid, name, attribute_kind(tuple(shape[1:])), ref, dtype, shape)
    return root


def write_xdmf(h5_path, xdmf_path, frames: list[FrameInfo] | None = None) -> str:
    """Write (atomically) the XDMF file describing every frame of a particles file.

    Call it on one rank only (rank 0). The file is written to a temporary file in the
    same directory and moved into place with :func:`os.replace`, so a reader never sees
    a half-written file.

    Parameters
    ----------
    h5_path : str or os.PathLike
        ``particles.h5`` (or its run directory).
    xdmf_path : str or os.PathLike
        XDMF file to write, e.g. ``DIR/particles.xdmf``.
    frames : list of FrameInfo, optional
        Frame index (``FrameWriter.frames``). When given, the HDF5 file is not opened
        (useful while the writer still holds it); otherwise it is read from the file.

    Returns
    -------
    str
        The path written.

    Raises
    ------
    ParsphError
        If the HDF5 file cannot be read or the XDMF file cannot be written.
    """
    h5_path = resolve_path(h5_path)
    xdmf_path = os.fspath(xdmf_path)
    if frames is None:
        with open_run(h5_path) as f:
            frames = _index(f)
            dim = int(f.attrs.get("dim", 0))
    else:
        dim = 0
    if dim not in (2, 3):
        dims = {fr.fields["x"][1][1] for fr in frames if "x" in fr.fields and len(fr.fields["x"][1]) == 2}
        if len(dims) > 1 or not dims.issubset({2, 3}):
            raise ParsphError(f"{h5_path}: positions 'x' have inconsistent or unsupported widths "
                              f"{sorted(dims)}; expected 2 or 3 columns")
        dim = dims.pop() if dims else 3
    out_dir = os.path.dirname(os.path.abspath(xdmf_path))
    h5_ref = os.path.relpath(os.path.abspath(h5_path), out_dir).replace(os.sep, "/")
    root = build_xdmf(frames, h5_ref, dim)
    ET.indent(root)
    text = '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    try:
        fd, tmp = tempfile.mkstemp(prefix=".particles-", suffix=".xdmf.tmp", dir=out_dir)
    except OSError as exc:
        raise ParsphError(f"cannot write {xdmf_path} ({exc}); check that {out_dir} exists "
                          "and is writable") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, xdmf_path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return xdmf_path


def xdmf_writer(xdmf_path):
    """A :class:`~parsph.io.hdf5.FrameWriter` ``on_frame`` callback that rewrites
    ``xdmf_path`` (atomically) from the writer's index after each frame; references are
    relative to its directory."""
    xdmf_path = os.fspath(xdmf_path)

    def on_frame(h5_path, frames):
        write_xdmf(h5_path, xdmf_path, frames=frames)

    return on_frame
