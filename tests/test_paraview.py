"""ParaView reads every field of ``particles.xdmf``: the real reader, not the XML.

A short 2D run (dam_break, IISPH) and a short 3D run (triaxial_light, TLSPH) are written
on the session's ranks (1 or 2: the suite runs under both), then rank 0 opens each with
Debian's ``pvbatch`` through ParaView's default reader for ``.xdmf`` (Xdmf3ReaderS) and
the older XDMF reader, and compares every time step, the number of points and of
vertex cells (what ParaView draws), the positions and the three velocity components with
``particles.h5``, particle by id.
Then the pvbatch script of docs/paraview.md (scripts/paraview_glyphs.py: particles by
phase, arrows of velocity) renders the run. Skipped only where ``pvbatch`` is not
installed (scripts/setup.sh installs it).
"""
import os
import shutil

import numpy as np
import pytest

from tests.scenes import pvbatch

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GLYPHS = os.path.join(ROOT, "scripts", "paraview_glyphs.py")
PVBATCH = shutil.which("pvbatch")

needs_pvbatch = pytest.mark.skipif(
    PVBATCH is None, reason="pvbatch not found: install Debian's paraview, python3-paraview "
    "and xvfb (scripts/setup.sh does) to run the ParaView reader test")

#: pvbatch script: for each reader and each time step, the point data as an .npz file;
#: then, in the same pvbatch (one X server per test: xvfb-run started right after another
#: one stopped can hand out a display the old server still holds), the glyph script.
READER = r'''
import json
import runpy
import sys

import numpy as np
from paraview import servermanager
from paraview.simple import OpenDataFile, XDMFReader
from vtkmodules.util.numpy_support import vtk_to_numpy

xdmf, out = sys.argv[1], sys.argv[2]
summary = {}
for label, make in (("default", lambda: OpenDataFile(xdmf)),
                    ("xdmf2", lambda: XDMFReader(FileNames=[xdmf]))):
    reader = make()
    times = [float(t) for t in reader.TimestepValues]
    summary[label] = {"reader": reader.GetXMLName(), "times": times}
    for k, t in enumerate(times):
        reader.UpdatePipeline(t)
        data = servermanager.Fetch(reader)
        if data.IsA("vtkMultiBlockDataSet"):
            data = data.GetBlock(0)
        pd = data.GetPointData()
        arrays = {pd.GetArrayName(i): vtk_to_numpy(pd.GetArray(i)) for i in range(pd.GetNumberOfArrays())}
        arrays["points"] = vtk_to_numpy(data.GetPoints().GetData())
        arrays["n_cells"] = np.array(data.GetNumberOfCells())  # vertex cells: what is drawn
        vectors = pd.GetVectors()
        arrays["vectors_name"] = np.array(vectors.GetName() if vectors else "")
        np.savez(f"{out}/{label}_{k}.npz", **arrays)
with open(f"{out}/summary.json", "w") as fh:
    json.dump(summary, fh)
if len(sys.argv) > 3:  # GLYPH_SCRIPT RUN_DIR PNG
    sys.argv = sys.argv[3:]
    runpy.run_path(sys.argv[0], run_name="__main__")
'''


SCENES = {
    2: ("dam_break", ["domain.particle_size=0.02", "run.end_time=0.01", "output.every=0.005"]),
    3: ("triaxial_light", ["domain.particle_size=0.01", "run.end_time=0.0008",
                           "output.every=0.0004"]),
}


@needs_pvbatch
@pytest.mark.parametrize("dim", [2, 3])
def test_paraview_reads_steps_points_and_velocity(comm, mpi_tmp_path, dim):
    import json

    from parsph.io import read_frame, read_frames
    from parsph.step.run import run
    from parsph.scene.loader import load_scene

    name, sets = SCENES[dim]
    scene = load_scene(name, sets)
    assert scene.domain.dim == dim
    out = os.path.join(mpi_tmp_path, "run")
    os.makedirs(out, exist_ok=True)
    run(scene, out, comm=comm, progress=False)
    comm.Barrier()
    if comm.rank != 0:
        return
    script = os.path.join(mpi_tmp_path, "read.py")
    with open(script, "w") as fh:
        fh.write(READER)
    dump = os.path.join(mpi_tmp_path, "pv")
    os.makedirs(dump)
    png = os.path.join(mpi_tmp_path, "glyphs.png")
    r = pvbatch(script, os.path.abspath(os.path.join(out, "particles.xdmf")), dump,
                 GLYPHS, out, png)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Skipping" not in r.stdout + r.stderr, r.stdout + r.stderr
    with open(os.path.join(dump, "summary.json")) as fh:
        summary = json.load(fh)
    assert summary["default"]["reader"] == "Xdmf3ReaderS"

    frames = read_frames(out)
    # 0, the first steps at or after 1 and 2 output intervals, and the last step (the
    # first sync step at or after run.end_time) unless it is the second interval's
    assert len(frames) in (3, 4)
    speeds = []
    for label, info in summary.items():
        assert info["times"] == [t for _, t in frames], label
        for k, (step, _) in enumerate(frames):
            h5 = read_frame(out, step)
            pv = dict(np.load(os.path.join(dump, f"{label}_{k}.npz")))
            where = f"{label} reader, step {step}"
            n = len(h5["id"])
            assert len(pv["points"]) == n and len(pv["v"]) == n, where
            assert int(pv["n_cells"]) == n, where
            assert set(h5) - {"x"} <= set(pv), (where, sorted(pv))
            assert str(pv["vectors_name"]) == "v", where
            o_h5, o_pv = np.argsort(h5["id"]), np.argsort(pv["id"])
            assert np.array_equal(pv["id"][o_pv], h5["id"][o_h5]), where
            v_pv, v_h5 = pv["v"][o_pv], h5["v"][o_h5]
            assert v_pv.shape == (n, 3), where
            assert np.array_equal(v_pv[:, :dim], v_h5), where
            assert not v_pv[:, dim:].any(), where  # z = 0 in 2D
            x_pv = pv["points"][o_pv]
            assert np.array_equal(x_pv[:, :dim], h5["x"][o_h5]) and not x_pv[:, dim:].any(), where
            for field in ("p", "phase", "rank"):
                assert np.array_equal(pv[field][o_pv], h5[field][o_h5]), (where, field)
            speeds.append(np.abs(v_h5).max(axis=0))
    # the runs move, so the comparison above compared real velocities on every axis
    assert (np.max(speeds, axis=0) > 1e-3).all()

    import matplotlib.image  # the picture of the glyph script

    image = matplotlib.image.imread(png)
    assert image.shape[:2] == (700, 1600)
    drawn = (image[:, :, :3] < 0.9).any(axis=2)  # not the white background
    assert drawn.mean() > 0.002, drawn.mean()


def test_docs_show_the_glyph_script():
    """docs/paraview.md shows scripts/paraview_glyphs.py as it is (the test above runs it)."""
    with open(os.path.join(ROOT, "docs", "paraview.md"), encoding="utf-8") as fh:
        doc = fh.read()
    with open(GLYPHS, encoding="utf-8") as fh:
        script = fh.read()
    assert f"```python\n{script}```" in doc
