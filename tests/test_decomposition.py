"""Tests of the decomposition package: Box, RCB, migrate, Halo.

Every test is valid at any rank count: the global particle set is generated identically
on every rank from a seeded generator, each rank keeps a slice, and the results are
compared with serial brute force on the global set.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from decomposition.box import Box
from decomposition.exchange import migrate
from decomposition.halo import Halo
from decomposition.partition import RCB, imbalance

FAST = settings(max_examples=30, deadline=None, database=None)


class OneProcessComm:
    """A stand-in communicator of ``size`` ranks where this process holds all the data.

    The RCB cuts depend only on the global set of positions, so building with all
    positions on this fake rank gives the tree a real ``size``-rank run would build.
    """

    rank = 0

    def __init__(self, size):
        self.size = size

    def Allreduce(self, send, recv, op=None):
        recv[...] = send

    def allreduce(self, value, op=None):
        return value

    def allgather(self, value):
        return [value]


def _split(comm, n, how="slice", seed=0):
    """Indices of the global rows this rank starts with."""
    if how == "slice":
        return np.array_split(np.arange(n), comm.size)[comm.rank]
    if how == "shuffled":
        perm = np.random.default_rng(seed).permutation(n)
        return perm[comm.rank::comm.size]
    raise ValueError(how)


def _lattice(shape, spacing=1.0):
    axes = [np.arange(k) * spacing + 0.5 * spacing for k in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(shape))


def _distribute(comm, X, box, how="slice"):
    """RCB from this rank's slice of X, then migrate ids and positions to the owners."""
    loc = _split(comm, len(X), how)
    rcb = RCB.build(comm, X[loc], box)
    owned = migrate(comm, {"x": X[loc], "id": loc.astype(np.int64)}, rcb.owner(X[loc]))
    return rcb, owned


def _gather_ids(comm, ids):
    return np.sort(np.concatenate(comm.allgather(np.asarray(ids))))


# --------------------------------------------------------------------------- Box
def test_box_wrap_and_outside():
    box = Box((0.0, -1.0, 2.0), (1.0, 1.0, 3.0), (True, False, True))
    x = np.array([[1.25, -2.0, 1.5], [-0.25, 0.5, 3.0], [1.0, 1.0, 2.0], [0.5, 0.0, 2.5]])
    w = box.wrap(x)
    assert w is not x
    np.testing.assert_allclose(w, [[0.25, -2.0, 2.5], [0.75, 0.5, 2.0], [0.0, 1.0, 2.0],
                                   [0.5, 0.0, 2.5]])
    np.testing.assert_array_equal(box.outside(x), [True, False, False, False])
    assert box.outside(np.array([[0.0, np.nan, 2.0]]))[0]
    assert box.dim == 3
    np.testing.assert_array_equal(box.length, [1.0, 2.0, 1.0])
    shifts = box.image_shifts()
    assert shifts.shape == (9, 3) and not shifts[0].any() and not shifts[:, 1].any()
    np.testing.assert_allclose(box.minimum_image(np.array([[0.75, 1.5, -0.6]])), [[-0.25, 1.5, 0.4]])


def test_box_rejects_bad_input():
    with pytest.raises(ValueError, match="exceed"):
        Box((0.0, 0.0), (1.0, 0.0), (False, False))
    with pytest.raises(ValueError, match="one entry per axis"):
        Box((0.0, 0.0), (1.0, 1.0, 1.0), (False, False))
    with pytest.raises(ValueError, match="2 \\(2D\\) or 3"):
        Box((0.0,), (1.0,), (False,))
    with pytest.raises(ValueError, match="components"):
        Box((0.0, 0.0), (1.0, 1.0), (True, True)).wrap(np.zeros((4, 3)))


@FAST
@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=40))
def test_box_wrap_property(values):
    box = Box((-0.3, 0.0), (0.7, 2.0), (True, False))
    x = np.array(values[: len(values) // 2 * 2]).reshape(-1, 2)
    w = box.wrap(x)
    assert np.all((w[:, 0] >= -0.3) & (w[:, 0] < 0.7))
    np.testing.assert_array_equal(w[:, 1], x[:, 1])
    k = (x[:, 0] - w[:, 0]) / 1.0
    np.testing.assert_allclose(k, np.round(k), atol=1e-9 * max(1.0, np.abs(x).max()))


# --------------------------------------------------------------------------- RCB
@pytest.mark.parametrize("dim, n", [(2, 1000), (3, 777), (2, 5)])
def test_rcb_balances_random_points(comm, dim, n):
    X = np.random.default_rng(dim * 100 + n).random((n, dim)) * np.arange(1, dim + 1)
    box = Box((0.0,) * dim, tuple(np.arange(1.0, dim + 1)), (False,) * dim)
    rcb, owned = _distribute(comm, X, box)
    counts = np.bincount(rcb.owner(X), minlength=comm.size)
    assert counts.sum() == n and counts.max() - counts.min() <= 1
    assert len(owned["id"]) == counts[comm.rank]
    assert imbalance(comm, len(owned["id"])) == pytest.approx(counts.max() * comm.size / n)


@pytest.mark.parametrize("shape", [(13, 11), (16, 16), (6, 5, 4), (7, 7)])
def test_rcb_balances_lattice_with_ties(comm, shape):
    X = _lattice(shape)
    box = Box((0.0,) * len(shape), tuple(float(k) for k in shape), (False,) * len(shape))
    rcb, owned = _distribute(comm, X, box)
    counts = np.bincount(rcb.owner(X), minlength=comm.size)
    assert counts.max() - counts.min() <= 1
    np.testing.assert_array_equal(rcb.owner(owned["x"]), comm.rank)


@FAST
@given(size=st.integers(1, 13), n=st.integers(0, 300), dim=st.sampled_from([2, 3]),
       seed=st.integers(0, 2**32 - 1), lattice=st.booleans())
def test_rcb_balances_any_rank_count(size, n, dim, seed, lattice):
    """Serial stand-in for `size` ranks (the cuts depend only on the global set)."""
    if lattice:
        side = max(1, round(n ** (1.0 / dim)))
        X = _lattice((side,) * dim)
    else:
        X = np.random.default_rng(seed).random((n, dim))
    box = Box((0.0,) * dim, (float(max(1, X.max(initial=1.0))) + 1.0,) * dim, (False,) * dim)
    rcb = RCB.build(OneProcessComm(size), X, box)
    assert rcb.n_ranks == size
    counts = np.bincount(rcb.owner(X), minlength=size)
    assert len(counts) == size and counts.max() - counts.min() <= 1
    _check_owner_in_subbox(rcb, X)


@pytest.mark.parametrize("size", [2, 3, 5, 8])
def test_rcb_negative_and_signed_zero_coordinates(size):
    """Keys cross zero; -0.0 and +0.0 are the same coordinate (serial stand-in)."""
    X = _lattice((9, 6), 0.25) - 1.125
    X[np.isclose(X, 0.0)] = 0.0
    X[::7][X[::7] == 0.0] = -0.0
    X = np.concatenate([X, np.random.default_rng(size).random((50, 2)) * 2.0 - 1.0])
    box = Box((-1.5, -1.5), (1.5, 1.5), (False, False))
    rcb = RCB.build(OneProcessComm(size), X, box)
    counts = np.bincount(rcb.owner(X), minlength=size)
    assert counts.max() - counts.min() <= 1
    np.testing.assert_array_equal(rcb.owner(X), rcb.owner(X + 0.0))
    _check_owner_in_subbox(rcb, X)


def _check_owner_in_subbox(rcb, X):
    owner = rcb.owner(X)
    lo, hi = rcb.subboxes()
    assert np.all((X >= lo[owner]) & (X <= hi[owner]))
    box = rcb.domain
    assert np.prod(hi - lo, axis=1).sum() == pytest.approx(np.prod(box.length))


@pytest.mark.parametrize("dim", [2, 3])
def test_rcb_owner_agrees_with_subbox(comm, dim):
    rng = np.random.default_rng(7)
    X = rng.random((400, dim))
    box = Box((0.0,) * dim, (1.0,) * dim, (False,) * dim)
    rcb, _ = _distribute(comm, X, box)
    probes = np.concatenate([rng.random((2000, dim)), X])
    _check_owner_in_subbox(rcb, probes)
    for r in range(comm.size):
        lo, hi = rcb.subbox(r)
        np.testing.assert_array_equal(lo, rcb.subboxes()[0][r])
        assert np.all(lo >= 0.0) and np.all(hi <= 1.0) and np.all(lo <= hi)
    with pytest.raises(ValueError, match="not in"):
        rcb.subbox(comm.size)


@pytest.mark.parametrize("weighted", [False, True])
def test_rcb_cuts_independent_of_distribution(comm, weighted):
    rng = np.random.default_rng(11)
    X = np.concatenate([rng.random((500, 3)), _lattice((5, 5, 4), 0.2)])
    W = 1.0 + 3.0 * rng.random(len(X)) if weighted else None
    box = Box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (False, True, False))
    trees = []
    for how in ("slice", "shuffled"):
        loc = _split(comm, len(X), how, seed=3)
        trees.append(RCB.build(comm, X[loc], box, None if W is None else W[loc]).to_arrays())
    a, b = trees
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), key
    everyone = comm.allgather(a)
    for other in everyone:
        assert all(np.array_equal(other[k], a[k]) for k in a)


def test_rcb_arrays_round_trip(comm):
    X = np.random.default_rng(5).random((300, 2))
    box = Box((0.0, 0.0), (1.0, 1.0), (True, False))
    rcb, _ = _distribute(comm, X, box)
    arrays = rcb.to_arrays()
    assert all(isinstance(v, np.ndarray) and v.dtype.kind in "iuf" for v in arrays.values())
    again = RCB.from_arrays({k: v.copy() for k, v in arrays.items()})
    assert again.domain == box
    np.testing.assert_array_equal(again.owner(X), rcb.owner(X))
    np.testing.assert_array_equal(again.subboxes()[0], rcb.subboxes()[0])
    with pytest.raises(ValueError, match="missing"):
        RCB.from_arrays({"axis": arrays["axis"]})


def test_rcb_weights(comm):
    rng = np.random.default_rng(2)
    X = rng.random((600, 2))
    W = np.where(X[:, 0] < 0.3, 5.0, 1.0)
    box = Box((0.0, 0.0), (1.0, 1.0), (False, False))
    loc = _split(comm, len(X), "slice")
    plain = RCB.build(comm, X[loc], box).to_arrays()
    ones = RCB.build(comm, X[loc], box, np.ones(len(loc))).to_arrays()
    assert all(np.array_equal(plain[k], ones[k]) for k in plain)
    rcb = RCB.build(comm, X[loc], box, W[loc])
    load = np.bincount(rcb.owner(X), weights=W, minlength=comm.size)
    assert np.abs(load - W.sum() / comm.size).max() <= (rcb.depth + 1) * W.max()
    with pytest.raises((ValueError, RuntimeError), match="weights"):
        RCB.build(comm, X[loc], box, -W[loc])


def test_rcb_rejects_bad_positions(comm):
    box = Box((0.0, 0.0), (1.0, 1.0), (False, False))
    x = np.full((1, 2), np.nan) if comm.rank == 0 else np.zeros((0, 2))
    with pytest.raises((ValueError, RuntimeError), match="NaN"):
        RCB.build(comm, x, box)


def test_imbalance(comm):
    assert imbalance(comm, 0) == 1.0
    assert imbalance(comm, 4) == pytest.approx(1.0)
    assert RCB.imbalance(comm, 10 if comm.rank == 0 else 0) == pytest.approx(comm.size)


# ----------------------------------------------------------------------- migrate
def _migration_case(comm, n, dim, seed, split_seed):
    """n random points in the unit box, shuffled over the ranks, their RCB, and the
    fields ``x``, ``id`` (global row), ``src`` (this rank) and ``local`` (local row)."""
    X = np.random.default_rng(seed).random((n, dim))
    box = Box((0.0,) * dim, (1.0,) * dim, (False,) * dim)
    loc = _split(comm, n, "shuffled", seed=split_seed)
    rcb = RCB.build(comm, X[loc], box)
    fields = {"x": X[loc], "id": loc.astype(np.int64),
              "src": np.full(len(loc), comm.rank, dtype=np.int32),
              "local": np.arange(len(loc), dtype=np.int64)}
    return X, loc, rcb, fields


def test_migrate_conserves_rows_and_lands_on_owner(comm):
    n, dim = 503, 3
    X, loc, rcb, fields = _migration_case(comm, n, dim, seed=9, split_seed=4)
    fields.update({"F": loc[:, None, None] * np.ones((1, dim, dim)),
                   "phase": (loc % 3).astype(np.uint8), "flag": loc % 2 == 0,
                   "empty": np.zeros((len(loc), 0))})
    out = migrate(comm, fields, rcb.owner(X[loc]))
    assert list(out) == list(fields)
    for name, a in out.items():
        assert a.dtype == fields[name].dtype and a.shape[1:] == fields[name].shape[1:]
    ids = out["id"]
    np.testing.assert_array_equal(_gather_ids(comm, ids), np.arange(n))
    np.testing.assert_array_equal(out["x"], X[ids])
    np.testing.assert_array_equal(out["F"], ids[:, None, None] * np.ones((1, dim, dim)))
    np.testing.assert_array_equal(out["phase"], ids % 3)
    np.testing.assert_array_equal(out["flag"], ids % 2 == 0)
    np.testing.assert_array_equal(rcb.owner(out["x"]), comm.rank)
    key = out["src"].astype(np.int64) * n + out["local"]
    assert np.all(np.diff(key) > 0)  # by source rank, then original local order


def test_migrate_puts_the_rows_flagged_last_after_the_others(comm):
    """migrate(..., last=): the same rows on the same owners as without it, the
    flagged rows after the others, each group by source rank, then local order; a
    flag on some ranks only is refused on every rank. One rank: nothing moves, and the
    rows stay as they are."""
    n, dim = 401, 2
    X, loc, rcb, fields = _migration_case(comm, n, dim, seed=12, split_seed=5)
    wall = loc % 4 == 1
    plain = migrate(comm, fields, rcb.owner(X[loc]))
    out = migrate(comm, fields, rcb.owner(X[loc]), last=wall)
    np.testing.assert_array_equal(np.sort(out["id"]), np.sort(plain["id"]))
    if comm.size == 1:
        assert out["id"] is fields["id"]
        return
    flagged = out["id"] % 4 == 1
    assert not np.any(flagged[:-1] & ~flagged[1:])  # no unflagged row after a flagged one
    for group in (~flagged, flagged):
        key = out["src"][group].astype(np.int64) * n + out["local"][group]
        assert np.all(np.diff(key) > 0)
    np.testing.assert_array_equal(out["x"], X[out["id"]])
    with pytest.raises(ValueError, match="last on some ranks"):
        migrate(comm, fields, rcb.owner(X[loc]), last=wall if comm.rank else None)


def test_migrate_rejects_bad_dest(comm):
    x = np.zeros((2, 2))
    dest = np.array([0, comm.size]) if comm.rank == 0 else np.zeros(2, dtype=np.int64)
    with pytest.raises((ValueError, RuntimeError), match="dest"):
        migrate(comm, {"x": x}, dest)


@pytest.mark.mpi
def test_migrate_everything_to_last_rank(comm):
    n = 10
    loc = _split(comm, n)
    out = migrate(comm, {"id": loc}, np.full(len(loc), comm.size - 1))
    expect = np.arange(n) if comm.rank == comm.size - 1 else np.zeros(0)
    np.testing.assert_array_equal(out["id"], expect)


# -------------------------------------------------------------------------- halo
def _check_halo_complete(comm, X, box, radius, how="slice"):
    """Owned + halo rows within radius of each owned row == brute force on the global set."""
    rcb, owned = _distribute(comm, X, box, how)
    halo = Halo.build(comm, rcb, owned["x"], radius, box)
    got = halo.exchange(owned)
    assert halo.n_halo == len(got["id"]) and got["x"].shape == (halo.n_halo, box.dim)
    xo, ido = owned["x"], owned["id"]
    allx = np.concatenate([xo, got["x"]])
    allid = np.concatenate([ido, got["id"]])
    d2 = ((xo[:, None, :] - allx[None, :, :]) ** 2).sum(axis=-1)
    counts = np.zeros((len(xo), len(X)), dtype=np.int64)
    rows, cols = np.nonzero(d2 <= radius * radius)
    np.add.at(counts, (rows, allid[cols]), 1)
    dx = box.minimum_image(xo[:, None, :] - X[None, :, :])
    d2b = (dx ** 2).sum(axis=-1)
    expect = (d2b <= radius * radius).astype(np.int64)
    clear = np.abs(np.sqrt(d2b) - radius) > 1e-9  # ignore pairs at the radius to rounding
    np.testing.assert_array_equal(counts[clear], expect[clear])
    return rcb, owned, halo, got


@pytest.mark.parametrize("dim, n, radius", [(2, 600, 0.08), (3, 500, 0.15), (2, 300, 0.4)])
def test_halo_equals_serial_neighbourhood(comm, dim, n, radius):
    X = np.random.default_rng(n + dim).random((n, dim))
    box = Box((0.0,) * dim, (1.0,) * dim, (False,) * dim)
    _, owned, halo, _ = _check_halo_complete(comm, X, box, radius)
    if comm.size == 1:
        assert halo.n_halo == 0 and halo.n_send == 0


@pytest.mark.parametrize("dim, periodic, n", [(2, (True, True), 300), (2, (True, False), 400),
                                              (3, (False, True, True), 500)])
def test_periodic_halo_equals_minimum_image_neighbourhood(comm, dim, periodic, n):
    radius = 0.1
    hi = (0.31, 0.5, 0.33)[:dim]  # about 3 radii wide
    box = Box((0.0,) * dim, hi, periodic)
    X = np.random.default_rng(n).random((n, dim)) * np.array(hi)
    _, owned, halo, got = _check_halo_complete(comm, X, box, radius, how="shuffled")
    assert halo.send_shift is not None and halo.n_halo > 0
    # Images land outside the box on periodic axes only.
    outside = (got["x"] < 0.0) | (got["x"] >= np.array(hi))
    assert not outside[:, ~np.array(periodic)].any()
    if comm.size == 1:
        assert outside.any(axis=1).all()  # every halo row on one rank is an image


def test_halo_reverse_add_counts_copies(comm):
    box = Box((0.0, 0.0), (0.5, 1.0), (True, False))
    X = np.random.default_rng(3).random((400, 2)) * [0.5, 1.0]
    rcb, owned, halo, got = _check_halo_complete(comm, X, box, 0.12)
    fields = {"idf": owned["id"].astype(np.float64), "v": np.ones((len(owned["id"]), 2)),
              "k": np.ones(len(owned["id"]), dtype=np.int32)}
    h = halo.exchange(fields)
    np.testing.assert_array_equal(h["idf"], got["id"].astype(np.float64))
    back = halo.reverse_add({"one": np.ones_like(h["idf"]), "v": h["v"], "k": h["k"]})
    all_halo_ids = np.concatenate(comm.allgather(got["id"]))
    copies = np.bincount(all_halo_ids, minlength=len(X))[owned["id"]]
    np.testing.assert_array_equal(back["one"], copies)
    np.testing.assert_array_equal(back["v"], np.repeat(copies[:, None], 2, axis=1))
    np.testing.assert_array_equal(back["k"], copies)
    assert back["k"].dtype == np.int32 and back["one"].shape == (halo.n_owned,)


def test_halo_arrival_order_is_deterministic(comm):
    box = Box((0.0, 0.0, 0.0), (1.0, 0.4, 1.0), (False, True, False))
    X = np.random.default_rng(8).random((500, 3)) * [1.0, 0.4, 1.0]
    rcb, owned = _distribute(comm, X, box)
    n = len(owned["id"])
    fields = {"x": owned["x"], "src": np.full(n, comm.rank, dtype=np.int64),
              "local": np.arange(n, dtype=np.int64)}
    h1 = Halo.build(comm, rcb, owned["x"], 0.1, box)
    h2 = Halo.build(comm, rcb, owned["x"], 0.1, box)
    np.testing.assert_array_equal(h1.send_index, h2.send_index)
    np.testing.assert_array_equal(h1.send_shift, h2.send_shift)
    a, b = h1.exchange(fields), h2.exchange(fields)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    key = a["src"] * (len(X) + 1) + a["local"]
    assert np.all(np.diff(key) >= 0)  # by source rank, then send (local) order
    np.testing.assert_array_equal(a["src"], np.repeat(np.arange(comm.size), h1.recv_counts))


@pytest.mark.parametrize("periodic", [False, True])
def test_halo_without_rows_is_the_halo_of_the_rows_that_stay(comm, periodic):
    """Halo.without (a solid view edited after a phase change): the pattern of the owned
    rows that stay gives the old exchange's rows of those that stay, in the old order,
    and the same rows (periodic images included) a geometric build of the rows that stay
    gives; nothing left out is sent."""
    box = Box((0.0, 0.0, 0.0), (1.0, 0.4, 1.0), (False, periodic, False))
    X = np.random.default_rng(12).random((600, 3)) * [1.0, 0.4, 1.0]
    rcb, owned = _distribute(comm, X, box)
    n = len(owned["id"])
    halo = Halo.build(comm, rcb, owned["x"], 0.12, box)
    keep = np.random.default_rng(comm.rank).random(n) > 0.2
    keep[: min(n, 3)] = False  # every rank drops some
    new, kept = halo.without(keep)
    assert new.n_owned == keep.sum() and len(kept) == halo.n_halo
    before = halo.exchange(owned)
    after = new.exchange({k: a[keep] for k, a in owned.items()})
    for k in owned:
        np.testing.assert_array_equal(after[k], before[k][kept])
    left = np.concatenate(comm.allgather(owned["id"][~keep]))
    assert not np.isin(after["id"], left).any()
    assert np.isin(before["id"][~kept], left).all()
    built = Halo.build(comm, rcb, owned["x"][keep], 0.12, box).exchange(
        {k: a[keep] for k, a in owned.items()})
    order = lambda h: np.lexsort((h["x"][:, 2], h["x"][:, 1], h["x"][:, 0], h["id"]))
    for k in owned:
        np.testing.assert_array_equal(after[k][order(after)], built[k][order(built)])
    with pytest.raises(ValueError, match="one per owned row"):
        halo.without(keep[:-1] if n else np.ones(1, bool))


@pytest.mark.parametrize("n", [0, 1])
@pytest.mark.parametrize("periodic", [False, True])
def test_empty_ranks_do_not_hang(comm, n, periodic):
    box = Box((0.0, 0.0), (1.0, 1.0), (periodic, False))
    X = np.full((n, 2), 0.05)
    rcb, owned = _distribute(comm, X, box)
    np.testing.assert_array_equal(_gather_ids(comm, owned["id"]), np.arange(n))
    assert imbalance(comm, len(owned["id"])) == pytest.approx(comm.size if n else 1.0)
    halo = Halo.build(comm, rcb, owned["x"], 0.2, box)
    got = halo.exchange(owned)
    assert got["x"].shape == (halo.n_halo, 2) and got["id"].dtype == np.int64
    back = halo.reverse_add({"one": np.ones(halo.n_halo)})
    assert back["one"].shape == (len(owned["id"]),)
    if periodic and len(owned["id"]):
        assert np.all(back["one"] >= 1)  # the periodic image of itself at least
    out = migrate(comm, owned, np.zeros(len(owned["id"]), dtype=np.int64))
    assert len(out["id"]) == (n if comm.rank == 0 else 0)


def test_halo_from_send_lists(comm):
    size, me = comm.size, comm.rank
    n = 3
    x = np.array([[me, 0.0], [me, 1.0], [me, 2.0]])
    send_index = [np.array([0, 2]) if r != me else np.array([1]) for r in range(size)]
    send_shift = [np.zeros((len(i), 2)) for i in send_index]
    send_shift[me][:] = [10.0, 0.0]
    halo = Halo.from_send_lists(comm, send_index, send_shift, n_owned=n)
    got = halo.exchange({"x": x, "id": np.arange(n) + 10 * me})
    expect_x = np.concatenate([[[r, 0.0], [r, 2.0]] if r != me else [[me + 10.0, 1.0]]
                               for r in range(size)])
    np.testing.assert_array_equal(got["x"], expect_x)
    back = halo.reverse_add({"c": np.ones(halo.n_halo)})
    np.testing.assert_array_equal(back["c"], [size - 1, 1, size - 1])
    with pytest.raises((ValueError, RuntimeError), match="send lists"):
        Halo.from_send_lists(comm, send_index[:-1] if me == 0 else send_index)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("periodic_first", [False, True])
def test_halo_send_list_of_many_ranks_is_the_brute_force_one(dim, periodic_first):
    """The pruned one-pass send list of ``Halo.build`` (12 sub-boxes, periodic images)
    is every (rank, row, image) within the radius, tested without pruning, in that order."""
    import itertools

    from decomposition.halo import _geometric_pattern, _near_ranks

    rng = np.random.default_rng(dim + 2 * periodic_first)
    periodic = (periodic_first,) + (True,) * (dim - 1)
    box = Box((0.0,) * dim, (1.0, 0.7, 0.5)[:dim], periodic)
    nx = (3, 2, 2)[:dim]
    cuts = [np.concatenate([[0.0], np.sort(rng.uniform(0.2, 0.8, k - 1)) * hi, [hi]])
            for k, hi in zip(nx, box.hi)]
    cells = list(itertools.product(*[range(k) for k in nx]))
    lo_all = np.array([[cuts[a][c[a]] for a in range(dim)] for c in cells])
    hi_all = np.array([[cuts[a][c[a] + 1] for a in range(dim)] for c in cells])
    shifts = box.image_shifts()
    radius = 0.08
    for me in (0, len(cells) - 1, 5):
        x = lo_all[me] + rng.random((800, dim)) * (hi_all[me] - lo_all[me])
        expect = sorted(
            (r, i, m) for i in range(len(x)) for m, s in enumerate(shifts)
            if m == 0 or np.linalg.norm(np.maximum(0, np.maximum(box.lo - x[i] - s,
                                                                 x[i] + s - box.hi))) <= radius
            for r in range(len(cells)) if (r, m) != (me, 0)
            and np.linalg.norm(np.maximum(0, np.maximum(lo_all[r] - x[i] - s,
                                                        x[i] + s - hi_all[r]))) <= radius)
        rows, dest, img = _geometric_pattern(x, radius, lo_all[me], hi_all[me], lo_all, hi_all,
                                             box.lo, box.hi, shifts,
                                             *_near_ranks(lo_all, hi_all, me, radius, shifts))
        assert list(zip(dest.tolist(), rows.tolist(), img.tolist())) == expect


@pytest.mark.parametrize("dim, periodic", [(2, (False, False)), (3, (False, False, False)),
                                           (2, (True, False))])
def test_coupled_halo_holds_the_neighbourhood_of_every_row_the_fluid_can_wet(comm, dim,
                                                                            periodic):
    """``coupled_halo`` (rows owned anywhere, as the mixed layout's two partitions leave
    them): owned + halo rows hold every row within 2h of each fluid row and of each row
    with a fluid row within 2h (the rows with current lists), and every fluid row within
    two radii of each row (the PPE's wall band), against brute force on the global set
    under the minimum image; and nothing farther than 3 radii from the fluid's bounding
    box (a long dry floor and a dry block stay home)."""
    from decomposition.coupled import coupled_halo

    rng = np.random.default_rng(dim + 7 * periodic[0])
    hi = np.array((3.0, 1.0, 1.0)[:dim])
    box = Box((0.0,) * dim, tuple(hi), periodic)
    radius = 0.12
    n_fluid, n_floor, n_block = 300, 900, 300
    fluid_x = rng.random((n_fluid, dim)) * np.array((0.5, 0.6, 1.0)[:dim]) + 0.05
    fluid_x[:, 0] += 2.3 if periodic[0] else 0.0  # across the periodic end from the floor's start
    floor = rng.random((n_floor, dim)) * hi
    floor[:, 1] *= 0.05  # a floor along the whole box
    block = rng.random((n_block, dim)) * np.array((0.4, 0.5, 1.0)[:dim]) + 0.05
    block[:, 0] += 0.4 if periodic[0] else 0.6  # beside the fluid; a dry far part
    X = np.concatenate([fluid_x, floor, block])
    kind = np.repeat([0, 1, 2], [n_fluid, n_floor, n_block])
    mine = _split(comm, len(X), "shuffled", seed=3)  # any owner is correct
    xo = X[mine]
    halo = coupled_halo(comm, xo, kind[mine] == 0, radius, box)
    got = halo.exchange({"x": xo, "id": mine.astype(np.int64)})
    allx = np.concatenate([xo, got["x"]])
    allid = np.concatenate([mine, got["id"]])
    d2 = ((xo[:, None, :] - allx[None, :, :]) ** 2).sum(axis=-1)
    dx = box.minimum_image(xo[:, None, :] - X[None, :, :])
    d2g = (dx ** 2).sum(axis=-1)
    wet = (kind[mine] == 0) | ((d2g < radius ** 2) & (kind == 0)[None, :]).any(axis=1)
    assert wet.sum() < len(mine) or len(mine) == 0
    for reach, rows, cols in ((radius, wet, np.ones(len(X), bool)),
                              (2 * radius, np.ones(len(mine), bool), kind == 0)):
        have = np.zeros((len(xo), len(X)), dtype=bool)
        r, c = np.nonzero(d2 < reach * reach)
        have[r, allid[c]] = True
        want = (d2g < reach * reach) & cols[None, :]
        clear = np.abs(np.sqrt(d2g) - reach) > 1e-9
        missing = want & ~have & clear
        missing[~rows] = False
        assert not missing.any(), (reach, int(missing.sum()))
    if not any(periodic):
        flo, fhi = fluid_x.min(axis=0), fluid_x.max(axis=0)
        gap = np.maximum(0.0, np.maximum(flo - got["x"], got["x"] - fhi))
        assert np.all(np.sqrt((gap ** 2).sum(axis=1)) <= 3 * radius + 1e-12)
        if comm.size > 1:
            assert halo.n_halo > 0
    else:
        assert halo.n_halo > 0  # images across the periodic end


def test_halo_rejects_bad_radius(comm):
    box = Box((0.0, 0.0), (0.3, 1.0), (True, False))
    rcb = RCB.build(comm, np.zeros((0, 2)), box)
    with pytest.raises((ValueError, RuntimeError), match="periodic box length"):
        Halo.build(comm, rcb, np.zeros((0, 2)), 0.35, box)


@pytest.mark.mpi
def test_rcb_uses_every_rank(comm):
    X = np.random.default_rng(1).random((64, 2))
    box = Box((0.0, 0.0), (1.0, 1.0), (False, False))
    rcb, owned = _distribute(comm, X, box)
    assert len(owned["id"]) > 0
    assert len(set(comm.allgather(tuple(rcb.subbox(comm.rank)[0])))) == comm.size


def test_halo_without_rows_checks_fields_like_a_real_exchange():
    """The one-rank, non-periodic pattern moves nothing: it returns empty rows of each field's
    shape and dtype, and still refuses fields shorter than the owned rows."""
    from mpi4py import MPI
    comm = MPI.COMM_SELF
    box = Box((0.0, 0.0), (1.0, 1.0), (False, False))
    x = np.random.default_rng(3).random((10, 2))
    halo = Halo.build(comm, RCB.build(comm, x, box), x, 0.2, box)
    assert halo.n_send == halo.n_halo == 0
    got = halo.exchange({"x": x, "F": np.zeros((10, 2, 2), dtype=np.float32)})
    assert got["x"].shape == (0, 2) and got["F"].shape == (0, 2, 2)
    assert got["F"].dtype == np.float32
    with pytest.raises(ValueError, match="rebuild the halo"):
        halo.exchange({"x": x[:5]})


def test_set_halo_writes_halo_rows_after_the_owned_ones_in_place():
    """The halo rows follow the owned rows, which are never copied while their array
    has room after them (the last step's halo, no row changed rank): the same memory is
    reused for a halo of equal or smaller size, a larger one gets a new array; fields
    absent from the halo get zero rows."""
    from parsph.core.particles import ParticleSet

    rng = np.random.default_rng(3)
    p = ParticleSet(2, {"id": np.arange(5), "x": rng.random((5, 2)), "m": np.ones(5)})
    owned_x = p["x"].copy()
    p.set_halo({"id": np.array([7, 8, 9]), "x": np.full((3, 2), 2.0), "m": np.full(3, 3.0)})
    assert p.n_total == 8 and list(p["id"]) == [0, 1, 2, 3, 4, 7, 8, 9]
    np.testing.assert_array_equal(p["x"][:5], owned_x)
    np.testing.assert_array_equal(p["x"][5:], 2.0)
    where = p["x"].__array_interface__["data"][0]
    # a new halo of two rows, no "m": in place, the owned rows untouched
    p.set_owned(p.owned_fields())
    p.set_halo({"id": np.array([11, 12]), "x": np.full((2, 2), 4.0)})
    assert p["x"].__array_interface__["data"][0] == where and p.n_total == 7
    np.testing.assert_array_equal(p["x"][:5], owned_x)
    np.testing.assert_array_equal(p["x"][5:], 4.0)
    np.testing.assert_array_equal(p["m"], [1, 1, 1, 1, 1, 0, 0])
    # a halo larger than the room: a new array with the same owned rows
    p.set_owned(p.owned_fields())
    p.set_halo({"id": np.arange(20, 30), "x": np.full((10, 2), 5.0), "m": np.ones(10)})
    assert p["x"].__array_interface__["data"][0] != where and p.n_total == 15
    np.testing.assert_array_equal(p["x"][:5], owned_x)
    np.testing.assert_array_equal(p["x"][5:], 5.0)
