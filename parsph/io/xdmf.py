"""XDMF 3 description of ``particles.h5`` so that ParaView (or VisIt) opens a run.

The XDMF file is a temporal collection with one ``Polyvertex`` grid per frame (one
vertex per particle) whose data stay in the HDF5 file, referenced relatively
(``particles.h5:/frames/000010/x``), so the run directory can be moved as a whole.

Field mapping
-------------
- Geometry: dataset ``x``; ``GeometryType="XY"`` in 2D, ``"XYZ"`` in 3D (``x`` is not
  repeated as an attribute; ParaView's ``coordsX``/``coordsY`` give its components).
- A field with one value per particle (``eps_p``, ``p``, ``phase``, ``id``, ...) is a
  ``Scalar`` attribute.
- In 3D a field of shape (N, 3) is a ``Vector`` attribute and (N, 3, 3) a ``Tensor``.
- In 2D, XDMF has no 2-component vector type, so a field of shape (N, 2) (``v``) is
  written as one ``Scalar`` attribute per component, ``v_x`` and ``v_y``, each a
  ``HyperSlab`` of the (N, 2) dataset (no data copied; every XDMF reader supports
  hyperslabs). In ParaView, ``v_x*iHat + v_y*jHat`` in the Calculator rebuilds the vector.
  Any other multi-component field (2D tensors, ...) is written the same way, one scalar
  per component (``F_xx``, ``F_xy``, ...).

Frames with no particle are left out (a grid of zero points stops some readers).
"""
from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET

import numpy as np

from parsph.errors import ParsphError
from parsph.io.hdf5 import FrameInfo, _index, frame_name, open_run, resolve_path

_AXES = "xyz"


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


def _component_items(grid, name: str, ref: str, dtype, shape):
    """One Scalar attribute per component of a multi-component dataset (hyperslabs)."""
    n, trail = shape[0], shape[1:]
    rank = len(shape)
    for index in np.ndindex(*trail):
        if all(i < 3 for i in index) and len(index) <= 2:
            suffix = "".join(_AXES[i] for i in index)
        else:
            suffix = "_".join(str(i) for i in index)
        attr = ET.SubElement(grid, "Attribute", {
            "Name": f"{name}_{suffix}", "AttributeType": "Scalar", "Center": "Node",
        })
        slab = ET.SubElement(attr, "DataItem", {
            "ItemType": "HyperSlab", "Dimensions": _dims((n,) + (1,) * (rank - 1)),
            "Type": "HyperSlab",
        })
        sel = ET.SubElement(slab, "DataItem", {
            "Dimensions": f"3 {rank}", "NumberType": "Int", "Format": "XML",
        })
        start = (0,) + tuple(index)
        stride = (1,) * rank
        count = (n,) + (1,) * (rank - 1)
        sel.text = " ".join(_dims(v) for v in (start, stride, count))
        _hdf_item(slab, ref, dtype, shape)


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
        ET.SubElement(grid, "Topology", {
            "TopologyType": "Polyvertex", "NumberOfElements": str(fr.n), "NodesPerElement": "1",
        })
        geometry = ET.SubElement(grid, "Geometry", {"GeometryType": "XY" if dim == 2 else "XYZ"})
        xdtype, xshape = fr.fields["x"]
        _hdf_item(geometry, f"{h5_ref}:/{group}/x", xdtype, xshape)
        for name in sorted(fr.fields):
            dtype, shape = fr.fields[name]
            if name == "x" or shape[0] != fr.n:
                continue  # the geometry itself, or not a per-particle field
            ref = f"{h5_ref}:/{group}/{name}"
            trail = tuple(shape[1:])
            if trail == ():
                kind = "Scalar"
            elif dim == 3 and trail == (3,):
                kind = "Vector"
            elif dim == 3 and trail == (3, 3):
                kind = "Tensor"
            else:
                _component_items(grid, name, ref, dtype, shape)
                continue
            attr = ET.SubElement(grid, "Attribute", {
                "Name": name, "AttributeType": kind, "Center": "Node",
            })
            _hdf_item(attr, ref, dtype, shape)
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
