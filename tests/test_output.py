"""Output: collective particles.h5, XDMF, stats.csv and PNG pictures.

Runs at 1 and 2 ranks: every rank writes its rows collectively, rank 0 reads the file
back serially after a barrier and checks it. Under 2 ranks a rank with zero rows is also
exercised.
"""
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from parsph.errors import ParsphError


def _rows(rank, n, dim, step=0):
    """Deterministic owned rows of a rank: ids interleaved across ranks."""
    ids = (np.arange(n, dtype=np.int64) * 7 + rank) * 3 + 1000
    x = ids[:, None] * 0.01 + np.arange(dim) + step
    v = -ids[:, None] * 0.1 + np.arange(dim) * 0.5
    return {
        "id": ids,
        "x": x,
        "v": v,
        "phase": (ids % 3).astype(np.uint8),
        "eps_p": ids * 1e-3,
        "p": ids * 10.0,
        "porosity": np.full(n, 0.4),
        "rho": ids * 2.0,
    }


def _counts(size):
    return [3 + 2 * r for r in range(size)]


def _all_rows(size, counts, dim, step=0):
    rows = [_rows(r, counts[r], dim, step) for r in range(size)]
    return {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}


def _by_id(frame):
    order = np.argsort(frame["id"])
    return {k: a[order] for k, a in frame.items()}


@pytest.mark.parametrize("dim", [2, 3])
def test_collective_write_schema_and_values(comm, mpi_tmp_path, dim):
    from parsph import __version__
    from parsph.io import FrameWriter, read_attrs, read_frame, read_frames

    counts = _counts(comm.size)
    with FrameWriter(mpi_tmp_path, comm, dim, attrs={"scene": "unit", "particle_size": 0.01}) as w:
        for step, time in ((0, 0.0), (10, 0.125)):
            w.write_frame(step, time, _rows(comm.rank, counts[comm.rank], dim, step))
    comm.Barrier()
    if comm.rank != 0:
        return
    path = os.path.join(mpi_tmp_path, "particles.h5")
    assert read_frames(mpi_tmp_path) == [(0, 0.0), (10, 0.125)]
    attrs = read_attrs(path)
    assert attrs["dim"] == dim and attrs["parsph_version"] == __version__
    assert attrs["scene"] == "unit" and attrs["particle_size"] == 0.01
    total = sum(counts)
    expected = _by_id(_all_rows(comm.size, counts, dim, 10))
    frame = read_frame(path, "last")
    dtypes = {"id": np.int64, "x": np.float64, "v": np.float64, "phase": np.uint8,
              "eps_p": np.float64, "p": np.float64, "porosity": np.float64,
              "rank": np.int32, "rho": np.float64}
    assert set(frame) == set(dtypes)
    for name, dt in dtypes.items():
        assert frame[name].dtype == dt, name
        shape = (total, dim) if name in ("x", "v") else (total,)
        assert frame[name].shape == shape, name
    # rows are ordered by rank; each id exactly once
    assert np.array_equal(frame["rank"], np.repeat(np.arange(comm.size), counts))
    assert np.unique(frame["id"]).size == total
    got = _by_id(frame)
    for name, a in expected.items():
        np.testing.assert_array_equal(got[name], a, err_msg=name)
    first = _by_id(read_frame(path, 0))
    np.testing.assert_array_equal(first["x"], _by_id(_all_rows(comm.size, counts, dim, 0))["x"])
    import h5py

    with h5py.File(path, "r") as f:
        g = f["frames/000010"]
        assert g.attrs["step"] == 10 and g.attrs["time"] == 0.125
    with pytest.raises(ParsphError, match="no frame at step 3"):
        read_frame(path, 3)


@pytest.mark.parametrize("empty", ["first", "last"])
def test_rank_with_zero_rows(comm, mpi_tmp_path, empty):
    """A rank that owns nothing takes part (at 1 rank the whole frame is empty)."""
    from parsph.io import FrameWriter, read_frame

    empty_rank = 0 if empty == "first" else comm.size - 1
    counts = [0 if r == empty_rank else 4 for r in range(comm.size)]
    dim = 2
    with FrameWriter(mpi_tmp_path, comm, dim) as w:
        rows = _rows(comm.rank, counts[comm.rank], dim)
        if comm.rank == empty_rank:  # an empty rank may hand over flat empty arrays
            rows["x"] = np.zeros(0)
            del rows["v"]
        w.write_frame(1, 0.5, rows)
    comm.Barrier()
    if comm.rank == 0:
        frame = read_frame(mpi_tmp_path)
        total = sum(counts)
        assert frame["x"].shape == (total, dim) and frame["id"].shape == (total,)
        assert empty_rank not in set(frame["rank"].tolist())
        expected = _by_id(_all_rows(comm.size, counts, dim))
        np.testing.assert_array_equal(_by_id(frame)["id"], expected["id"])
        np.testing.assert_array_equal(_by_id(frame)["p"], expected["p"])


def test_missing_fields_are_zeros(comm, mpi_tmp_path):
    from parsph.io import FrameWriter, read_frame

    n = 2 + comm.rank
    with FrameWriter(mpi_tmp_path, comm, 3) as w:
        w.write_frame(0, 0.0, {"id": np.arange(n) + 100 * comm.rank, "x": np.ones((n, 3))})
    comm.Barrier()
    if comm.rank == 0:
        frame = read_frame(mpi_tmp_path)
        total = sum(2 + r for r in range(comm.size))
        assert frame["v"].shape == (total, 3) and not frame["v"].any()
        for name in ("eps_p", "p", "porosity", "phase"):
            assert frame[name].shape == (total,) and not frame[name].any(), name
        assert frame["phase"].dtype == np.uint8
        assert np.array_equal(frame["rank"], np.repeat(np.arange(comm.size), [2 + r for r in range(comm.size)]))


def test_append_replaces_step_and_bad_input(comm, mpi_tmp_path):
    from parsph.io import FrameWriter, read_frame, read_frames

    rows = _rows(comm.rank, 3, 2)
    with FrameWriter(mpi_tmp_path, comm, 2) as w:
        w.write_frame(0, 0.0, rows)
        w.write_frame(1, 0.1, rows)
        with pytest.raises(ParsphError, match="shape"):
            w.write_frame(2, 0.2, dict(rows, x=np.ones((3, 3))))
    with FrameWriter(mpi_tmp_path, comm, 2, mode="a") as w:
        assert [fr.step for fr in w.frames] == [0, 1]
        w.write_frame(1, 0.1, dict(rows, p=np.full(3, 7.0)))
        w.write_frame(2, 0.2, rows)
    with pytest.raises(ParsphError, match="dim=2"):
        FrameWriter(mpi_tmp_path, comm, 3, mode="a")
    comm.Barrier()
    if comm.rank == 0:
        assert read_frames(mpi_tmp_path) == [(0, 0.0), (1, 0.1), (2, 0.2)]
        assert np.all(read_frame(mpi_tmp_path, 1)["p"] == 7.0)
    # a restart from the checkpoint of step 1 drops the frames a killed run wrote later
    with FrameWriter(mpi_tmp_path, comm, 2, mode="a") as w:
        w.drop_frames_after(1)
        assert [fr.step for fr in w.frames] == [0, 1]
        w.write_frame(3, 0.3, rows)
    comm.Barrier()
    if comm.rank == 0:
        assert read_frames(mpi_tmp_path) == [(0, 0.0), (1, 0.1), (3, 0.3)]


@pytest.mark.mpi
def test_ranks_disagreeing_on_extra_fields_fail_everywhere(comm, mpi_tmp_path):
    from parsph.io import FrameWriter

    rows = _rows(comm.rank, 2, 2)
    if comm.rank == 1:
        rows["extra"] = np.ones(2)
    with FrameWriter(mpi_tmp_path, comm, 2) as w:
        with pytest.raises(ParsphError, match="disagree"):
            w.write_frame(0, 0.0, rows)


def _check_xdmf(xdmf_path, dim, n_frames):
    import h5py

    root = ET.parse(xdmf_path).getroot()
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    series = root.find("Domain/Grid")
    assert series.get("CollectionType") == "Temporal"
    grids = series.findall("Grid")
    assert len(grids) == n_frames
    base = os.path.dirname(xdmf_path)
    for grid in grids:
        topology = grid.find("Topology")
        assert topology.get("TopologyType") == "Polyvertex"
        fname, ref = topology.find("DataItem").text.strip().split(":", 1)
        with h5py.File(os.path.join(base, fname), "r") as f:  # explicit connectivity
            n = int(topology.get("NumberOfElements"))
            assert np.array_equal(f[ref][()], np.arange(n))
        assert grid.find("Geometry").get("GeometryType") == ("XY" if dim == 2 else "XYZ")
        float(grid.find("Time").get("Value"))
        names = {a.get("Name"): a.get("AttributeType") for a in grid.findall("Attribute")}
        assert names["v"] == "Vector" and names["sigma"] == "Tensor"
        assert names["eps_p"] == names["p"] == names["phase"] == "Scalar"
        assert names["extra4"] == "Matrix"
        for a in grid.findall("Attribute"):  # plain HDF items only: ParaView reads no other
            items = a.findall("DataItem")
            assert len(items) == 1 and items[0].get("Format") == "HDF" and not list(items[0])
        # vectors and tensors of 3 (3 x 3) components, in 2D through their view (z = 0)
        fname, ref = grid.find("Attribute[@Name='v']/DataItem").text.strip().split(":", 1)
        with h5py.File(os.path.join(base, fname), "r") as f:
            group = ref.rsplit("/xdmf/", 1)[0] if dim == 2 else ref.rsplit("/", 1)[0]
            v, view = f[group]["v"][()], f[ref][()]
            sigma = f[group]["sigma"][()]
            sigma_view = f[ref.replace("/v", "/sigma")][()]
        assert view.shape == (len(v), 3) and sigma_view.shape == (len(v), 3, 3)
        assert np.array_equal(view[:, :dim], v) and not view[:, dim:].any()
        assert np.array_equal(sigma_view[:, :dim, :dim], sigma)
        assert not sigma_view[:, dim:].any() and not sigma_view[:, :, dim:].any()
        for item in grid.iter("DataItem"):
            if item.get("Format") != "HDF":
                continue
            fname, dset = item.text.strip().split(":", 1)
            assert not os.path.isabs(fname)
            with h5py.File(os.path.join(base, fname), "r") as f:
                assert dset in f, dset
                shape = tuple(int(s) for s in item.get("Dimensions").split())
                assert f[dset].shape == shape


@pytest.mark.parametrize("dim", [2, 3])
def test_xdmf_describes_every_frame(comm, mpi_tmp_path, dim):
    from parsph.io import FrameWriter, write_xdmf, xdmf_writer

    live = os.path.join(mpi_tmp_path, "particles.xdmf")
    with FrameWriter(mpi_tmp_path, comm, dim, on_frame=xdmf_writer(live)) as w:
        for step in range(3):
            rows = _rows(comm.rank, 2 + comm.rank, dim, step)
            rows["sigma"] = rows["v"][:, :, None] * rows["x"][:, None, :]
            rows["extra4"] = np.repeat(rows["p"][:, None], 4, axis=1)
            w.write_frame(step * 5, step * 0.01, rows)
    comm.Barrier()
    if comm.rank == 0:
        _check_xdmf(live, dim, 3)  # rewritten after each frame from the writer's index
        os.makedirs(os.path.join(mpi_tmp_path, "view"))
        other = os.path.join(mpi_tmp_path, "view", "run.xdmf")
        write_xdmf(mpi_tmp_path, other)  # built from the file, references ../particles.h5
        _check_xdmf(other, dim, 3)
        assert not [p for p in os.listdir(mpi_tmp_path) if p.endswith(".tmp")]


def test_stats_csv_round_trip(comm, mpi_tmp_path):
    from parsph.io import StatsWriter
    from parsph.io.stats import read_stats

    path = os.path.join(mpi_tmp_path, "stats.csv")
    cols = ["step", "time", "dt", "ksp_its", "n_fluid", "stage"]
    with StatsWriter(path, cols, enabled=comm.rank == 0) as s:
        s.write({"step": 1, "time": 0.1, "dt": 1e-5, "ksp_its": np.int32(12), "n_fluid": 0})
        s.write({"step": 2, "time": 1 / 3, "dt": np.float64(2.5e-5), "stage": "x"})
        with pytest.raises(ValueError, match=r"\['bogus'\]"):
            s.write({"step": 3, "bogus": 1.0})
    comm.Barrier()
    if comm.rank == 0:
        with open(path) as fh:
            lines = fh.read().splitlines()
        assert lines[0] == "step,time,dt,ksp_its,n_fluid,stage"
        assert lines[1] == "1,0.1,1e-05,12,0,"
        assert len(lines) == 3
        data = read_stats(path)
        assert data["time"][1] == 1 / 3 and data["dt"][1] == 2.5e-5
        assert np.isnan(data["ksp_its"][1])
    comm.Barrier()
    with StatsWriter(path, cols, enabled=comm.rank == 0, mode="a") as s:
        s.write({"step": 3})
    with pytest.raises(ParsphError, match="differ"):
        StatsWriter(path, ["step"], enabled=True, mode="a")
    comm.Barrier()
    if comm.rank == 0:
        assert read_stats(path)["step"].tolist() == [1.0, 2.0, 3.0]


def test_stats_rows_reach_the_file_by_time_flush_or_close(tmp_path):
    """Rows are buffered for at most ``flush_seconds``; ``flush`` and ``close`` write them;
    text cells are quoted as the csv module quotes them."""
    import csv

    from parsph.io import StatsWriter

    path = tmp_path / "stats.csv"

    def rows():
        with open(path, newline="") as fh:
            return list(csv.reader(fh))[1:]

    with StatsWriter(path, ["step", "note"], enabled=True, flush_seconds=3600.0) as s:
        s.write({"step": 1, "note": 'a, "b"'})
        s.write({"step": 2, "note": "line\nbreak"})
        assert rows() == []  # within the hour: buffered
        with pytest.raises(TypeError, match="not a number"):
            s.write({"step": [5]})  # refused at once, not at the flush
        s.flush()
        assert rows() == [["1", 'a, "b"'], ["2", "line\nbreak"]]
        s.write({"step": 3})
    assert rows()[-1] == ["3", ""]  # closed: written
    with StatsWriter(path, ["step", "note"], enabled=True, mode="a", flush_seconds=0.0) as s:
        s.write({"step": 4})
        assert rows()[-1] == ["4", ""]  # flushed after the row


def _serial_run(directory, dim, n_frames=1, n=60, empty=False):
    """Write a small run from one rank (COMM_SELF)."""
    from mpi4py import MPI

    from parsph.io import FrameWriter

    rng = np.random.default_rng(1)
    with FrameWriter(directory, MPI.COMM_SELF, dim,
                     attrs={"scene": f"plot{dim}d", "particle_size": 0.05}) as w:
        for k in range(n_frames):
            m = 0 if empty else n
            x = rng.random((m, dim)) * np.array([2.0, 0.6, 0.8][:dim])
            phase = np.where(x[:, 0] < 0.2, 2, np.where(x[:, 0] > 1.0, 1, 0)).astype(np.uint8)
            w.write_frame(k, 0.1 * k, {"id": np.arange(m), "x": x, "v": rng.normal(size=(m, dim)),
                                       "phase": phase, "eps_p": rng.random(m)})


@pytest.mark.parametrize("dim", [2, 3])
def test_plot_writes_png(comm, mpi_tmp_path, dim):
    if comm.rank != 0:
        return
    from parsph.io import plot_run

    _serial_run(mpi_tmp_path, dim, n_frames=2)
    paths = plot_run(mpi_tmp_path, frames="all", dpi=50)
    assert [os.path.basename(p) for p in paths] == ["frame_000000.png", "frame_000001.png"]
    for p in paths:
        with open(p, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
        assert os.path.getsize(p) > 1000
    one = plot_run(os.path.join(mpi_tmp_path, "particles.h5"), out=os.path.join(mpi_tmp_path, "o"),
                   color_by=["p", "rank"], frames=[1], dpi=50)
    assert len(one) == 1 and os.path.getsize(one[0]) > 0


def test_plot_errors_name_the_file(comm, mpi_tmp_path):
    if comm.rank != 0:
        return
    from parsph.io import plot_run

    missing = os.path.join(mpi_tmp_path, "nothing")
    with pytest.raises(ParsphError, match="no such file"):
        plot_run(missing)
    bogus = os.path.join(mpi_tmp_path, "bogus.h5")
    with open(bogus, "w") as fh:
        fh.write("not hdf5")
    with pytest.raises(ParsphError, match="bogus.h5 is not an HDF5 file"):
        plot_run(bogus)
    run = os.path.join(mpi_tmp_path, "empty")
    os.makedirs(run)
    _serial_run(run, 2, empty=True)
    with pytest.raises(ParsphError, match="no particles"):
        plot_run(run)
    _serial_run(run, 2)
    with pytest.raises(ParsphError, match="cannot colour by 'nope'"):
        plot_run(run, color_by=["nope"])
    with pytest.raises(ParsphError, match="no frame at step 9"):
        plot_run(run, frames=[9])
