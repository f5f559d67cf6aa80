"""Neighbour search (parsph.core.neighbours) against brute force; density summation, eq. (33).

Serial unit tests: under ``mpirun -n 2`` every rank runs them independently (no
collective calls), each with its own hypothesis draws.
"""
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from parsph.core import kernel as K
from parsph.core.density import density_summation
from parsph.core.neighbours import (build_csr, cell_order, pair_count, row_lengths, row_of_pairs,
                                   without_rows)

SETTINGS = settings(max_examples=80, deadline=None, database=None)


def brute_force(x, n_query, radius):
    """Reference CSR lists: squared distance summed over the axes in order, < radius**2."""
    x = np.asarray(x, dtype=np.float64)
    rows = []
    for i in range(n_query):
        d = x - x[i]
        r2 = d[:, 0] * d[:, 0]
        for a in range(1, x.shape[1]):
            r2 = r2 + d[:, a] * d[:, a]
        ok = r2 < radius * radius
        ok[i] = False
        rows.append(np.flatnonzero(ok))
    indptr = np.zeros(n_query + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows], dtype=np.int64)
    indices = np.concatenate(rows + [np.empty(0, np.int64)]).astype(np.int32)
    return indptr, indices


def check_against_brute_force(x, n_query, radius):
    indptr, indices = build_csr(x, n_query, radius)
    assert indptr.dtype == np.int64 and indptr.shape == (n_query + 1,)
    assert indices.dtype == np.int32 and indices.shape == (indptr[-1],)
    assert indptr[0] == 0 and np.all(np.diff(indptr) >= 0)
    for i in range(n_query):
        row = indices[indptr[i] : indptr[i + 1]]
        assert np.all(np.diff(row) > 0), "row not strictly ascending"
        assert i not in row, "self in its own row"
    ref_ptr, ref_idx = brute_force(x, n_query, radius)
    assert np.array_equal(indptr, ref_ptr)
    assert np.array_equal(indices, ref_idx)
    return indptr, indices


@st.composite
def point_sets(draw):
    """(x, n_query, radius): uniform, clustered, duplicated, lattice or far-flung sets."""
    dim = draw(st.sampled_from([1, 2, 3]))
    n = draw(st.one_of(st.integers(0, 4), st.integers(5, 60), st.integers(61, 400)))
    kinds = ["uniform", "clusters", "duplicates", "lattice", "huge_box", "line"]
    kind = draw(st.sampled_from(kinds))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    radius = draw(st.sampled_from([0.02, 0.1, 0.25, 0.7, 3.0]))
    if kind == "uniform":
        x = rng.uniform(-1.0, 1.0, (n, dim)) * draw(st.sampled_from([1.0, 10.0]))
    elif kind == "clusters":
        centres = rng.uniform(-5.0, 5.0, (max(1, n // 30), dim))
        x = centres[rng.integers(0, len(centres), n)] + 0.05 * rng.standard_normal((n, dim))
    elif kind == "duplicates":
        base = rng.uniform(0.0, 1.0, (max(1, n // 4), dim))
        x = base[rng.integers(0, len(base), n)]
    elif kind == "lattice":
        # exact lattice distances: radius ties with pair distances (strict inequality)
        side = max(1, int(round(n ** (1.0 / dim))))
        g = np.arange(side) * 0.1
        x = np.array(list(itertools.product(g, repeat=dim)), dtype=np.float64)[:n]
        # far from the origin the rounded coordinates put some ties just inside/outside
        x = x + draw(st.sampled_from([0.0, -3.7e3, 1e6 + 0.3]))
        radius = draw(st.sampled_from([0.1, 0.2, 0.1 * np.sqrt(2.0), 0.25]))
    elif kind == "huge_box":
        # a far outlier: the dense grid would need ~1e10 cells per axis (sparse layout)
        x = rng.uniform(0.0, 1.0, (n, dim))
        if n:
            x[-1] = 1e9 * rng.choice([-1.0, 1.0], dim)
        radius = draw(st.sampled_from([0.05, 0.2]))
    else:  # points on a line in a higher-dimensional space
        t = rng.uniform(0.0, 3.0, n)
        x = np.outer(t, rng.uniform(-1.0, 1.0, dim))
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.shape[0]
    n_query = draw(st.integers(0, n))
    return x, n_query, radius


@SETTINGS
@given(point_sets())
def test_equals_brute_force(case):
    x, n_query, radius = case
    check_against_brute_force(x, n_query, radius)


@pytest.mark.parametrize("direct", [True, False])
@SETTINGS
@given(point_sets())
def test_cross_search_is_the_target_part_of_build_csr(direct, case):
    """``build_cross_csr(x[:k], x[k:])``: each query's neighbours among the targets only,
    the same pairs (and order) as the full search's lists restricted to the targets; on
    every kind of set (duplicates, ties at the radius, huge boxes, lines), by the direct
    loop of small sets and by the cell search alike."""
    from parsph.core import cross

    x, k, radius = case
    saved, cross.DIRECT_PAIRS = cross.DIRECT_PAIRS, (1 << 62 if direct else -1)
    try:
        indptr, indices = cross.build_cross_csr(x[:k], x[k:], radius)
    finally:
        cross.DIRECT_PAIRS = saved
    ref_ptr, ref_idx = brute_force(x, k, radius)
    assert indptr.dtype == np.int64 and indices.dtype == np.int32
    assert indptr.shape == (k + 1,)
    for i in range(k):
        ref = ref_idx[ref_ptr[i]:ref_ptr[i + 1]]
        assert np.array_equal(indices[indptr[i]:indptr[i + 1]], ref[ref >= k] - k)


def test_cross_search_checks_its_arguments():
    from parsph.core.cross import build_cross_csr

    ptr, idx = build_cross_csr(np.zeros((3, 2)), np.zeros((0, 2)), 0.1)
    assert ptr.tolist() == [0, 0, 0, 0] and idx.size == 0
    with pytest.raises(ValueError, match="dimension"):
        build_cross_csr(np.zeros((3, 2)), np.zeros((2, 3)), 0.1)
    with pytest.raises(ValueError, match="radius"):
        build_cross_csr(np.zeros((3, 2)), np.zeros((2, 2)), 0.0)
    with pytest.raises(ValueError, match="NaN"):
        build_cross_csr(np.full((1, 2), np.nan), np.zeros((2, 2)), 0.1)


@SETTINGS
@given(
    x=hnp.arrays(
        np.float64,
        st.tuples(st.integers(0, 40), st.sampled_from([2, 3])),
        elements=st.sampled_from([0.0, 0.1, 0.2, 0.25, 0.3, -0.1, 1.0, 1e-300, 7.5]),
    ),
    radius=st.sampled_from([0.1, 0.2, 0.15, 1.0]),
    data=st.data(),
)
def test_equals_brute_force_on_ties(x, radius, data):
    """Few distinct coordinates: many duplicates and pairs exactly at the radius."""
    n_query = data.draw(st.integers(0, x.shape[0]))
    check_against_brute_force(x, n_query, radius)


@pytest.mark.parametrize("offset", [0.0, 12345.678, -1e7])
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_pairs_at_the_radius(dim, offset):
    """Distances within a few ulps of the radius, along axes and diagonals."""
    radius = 0.3
    pts = [np.zeros(dim)]
    for k in range(dim):
        for sign in (1.0, -1.0):
            for v in (radius, np.nextafter(radius, 0.0), np.nextafter(radius, 1.0), 2 * radius):
                p = np.zeros(dim)
                p[k] = sign * v
                pts.append(p)
    diag = np.full(dim, radius / np.sqrt(dim))
    for f in (1.0 - 1e-15, 1.0, 1.0 + 1e-15):
        pts.append(diag * f)
        pts.append(-diag * f)
    x = np.array(pts) + offset
    indptr, indices = check_against_brute_force(x, len(x), radius)
    if offset == 0.0:  # on-axis points at exactly the radius are not neighbours of 0
        assert 1 not in indices[: indptr[1]] and 2 in indices[: indptr[1]]


@pytest.mark.parametrize("dim", [2, 3])
def test_larger_random_set_and_halo_rows(dim):
    rng = np.random.default_rng(7)
    x = rng.uniform(0.0, 1.0, (3000, dim))
    indptr, indices = check_against_brute_force(x, 2000, 0.08)
    assert indices.max() >= 2000  # halo rows appear as neighbours
    # symmetric among query rows
    rows = row_of_pairs(indptr)
    q = indices < 2000
    pairs = set(zip(rows[q].tolist(), indices[q].tolist()))
    assert all((j, i) in pairs for i, j in pairs)


@pytest.mark.parametrize("dim", [2, 3])
def test_lists_without_rows_are_the_lists_of_the_rows_that_stay(dim):
    """without_rows (the solid's view edited after a phase change): the lists of the
    rows that stay, query and halo rows left out alike, are build_csr's of what stays,
    entry for entry; ``entry`` picks the kept pairs of a per-pair array, ``lost`` the
    rows that lost a neighbour."""
    rng = np.random.default_rng(17 + dim)
    x = rng.uniform(0.0, 1.0, (2500, dim))
    nq, radius = 1800, 0.09
    indptr, indices = build_csr(x, nq, radius)
    keep = rng.random(len(x)) > 0.005  # a few rows leave, as in a phase change
    renumber = np.full(len(x), -1, dtype=indices.dtype)
    kq = int(keep[:nq].sum())
    renumber[:nq][keep[:nq]] = np.arange(kq)
    renumber[nq:][keep[nq:]] = kq + np.arange(int(keep[nq:].sum()))
    ptr2, ind2, entry, lost = without_rows(indptr, indices, keep[:nq], renumber)
    ref_ptr, ref_ind = build_csr(x[np.concatenate([np.flatnonzero(keep[:nq]),
                                                     nq + np.flatnonzero(keep[nq:])])],
                                 kq, radius)
    np.testing.assert_array_equal(ptr2, ref_ptr)
    np.testing.assert_array_equal(ind2, ref_ind)
    pair = np.arange(len(indices))  # a per-pair array: its kept entries are the new pairs'
    rows = row_of_pairs(indptr)
    np.testing.assert_array_equal(renumber[indices[pair[entry]]], ind2)
    np.testing.assert_array_equal(renumber[rows[pair[entry]]], row_of_pairs(ptr2))
    old_rows = np.flatnonzero(keep[:nq])
    expect = np.diff(indptr)[old_rows] != np.diff(ptr2)
    np.testing.assert_array_equal(lost, expect)
    assert lost.any() and not lost.all()


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_sparse_layout(monkeypatch, dim):
    """The sorted-occupied-cells layout (huge boxes) gives the same lists."""
    import parsph.core.cells as nb

    calls = []
    real = nb._sort_sparse

    def spy(*args):
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(nb, "_sort_sparse", spy)
    rng = np.random.default_rng(11)
    x = rng.uniform(0.0, 1.0, (500, dim))
    x[0] = 1e12  # a far outlier
    check_against_brute_force(x, 400, 0.1)
    assert len(calls) == 1
    # force the sparse layout on a compact set too
    monkeypatch.setattr(nb, "_DENSE_PER_PARTICLE", 0)
    monkeypatch.setattr(nb, "_DENSE_MIN", 0)
    check_against_brute_force(x[1:], 300, 0.1)
    check_against_brute_force(np.round(x[1:] * 10) / 10, 499, 0.1)
    assert len(calls) == 3


def test_pairs_beyond_the_first_room_are_recorded(monkeypatch):
    """The count records the pairs for the fill in an array that grows when the room its
    sample gave is short: here every pair is a neighbour pair (179,700 of them) and the
    first room is made a single entry."""
    import parsph.core.neighbours as nb

    rng = np.random.default_rng(5)
    x = rng.uniform(0.0, 1.0, (600, 3))
    monkeypatch.setattr(nb, "_upper_pairs_estimate", lambda *args: 1)
    indptr, _ = check_against_brute_force(x, 600, 2.0)
    assert np.all(np.diff(indptr) == 599)


def test_gather_fill_gives_the_same_lists(monkeypatch):
    """The gather-and-sort fill (large, incoherently ordered sets) agrees."""
    import parsph.core.neighbours as nb

    rng = np.random.default_rng(13)
    x = rng.uniform(0.0, 1.0, (2000, 3))
    ref = build_csr(x, 1500, 0.12)
    monkeypatch.setattr(nb, "_GATHER_MIN_ROWS", 0)
    monkeypatch.setattr(nb, "_GATHER_DISORDER", -1.0)
    got = check_against_brute_force(x, 1500, 0.12)
    assert np.array_equal(ref[0], got[0]) and np.array_equal(ref[1], got[1])


@pytest.mark.parametrize("gather", [False, True])
def test_lists_come_in_the_visiting_order(monkeypatch, gather):
    """build_csr(..., visit=): each list holds the same rows as without it, in the
    order of the permutation (the rows as the fluid's systems number them: a halo from
    a lower rank first), by both fills; a visit of the wrong length is refused."""
    import parsph.core.neighbours as nb

    rng = np.random.default_rng(17)
    x = rng.uniform(0.0, 1.0, (1500, 3))
    n_query = 1100
    visit = np.concatenate([np.arange(n_query, 1500), rng.permutation(n_query)])
    place = np.empty(1500, dtype=np.int64)
    place[visit] = np.arange(1500)
    ref = build_csr(x, n_query, 0.12)
    if gather:
        monkeypatch.setattr(nb, "_GATHER_MIN_ROWS", 0)
        monkeypatch.setattr(nb, "_GATHER_DISORDER", -1.0)
    got = build_csr(x, n_query, 0.12, visit=visit)
    assert np.array_equal(ref[0], got[0])
    for i in range(n_query):
        mine = got[1][got[0][i]:got[0][i + 1]]
        assert np.array_equal(np.sort(mine), ref[1][ref[0][i]:ref[0][i + 1]])
        assert np.all(np.diff(place[mine]) > 0), i
    with pytest.raises(ValueError, match="visit"):
        build_csr(x, n_query, 0.12, visit=visit[:-1])


def brute_force_active(x, n_query, radius, active):
    """Reference lists with ``active``: an inactive row keeps its row only if an active
    row is among its neighbours (empty otherwise)."""
    ptr, idx = brute_force(x, n_query, radius)
    rows = [idx[ptr[i]:ptr[i + 1]] for i in range(n_query)]
    rows = [r if active[i] or active[r].any() else r[:0] for i, r in enumerate(rows)]
    indptr = np.zeros(n_query + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows], dtype=np.int64)
    return indptr, np.concatenate(rows + [np.empty(0, np.int32)]).astype(np.int32)


@given(case=point_sets(), data=st.data())
@SETTINGS
def test_active_rows_keep_lists_only_where_an_active_row_is_near(case, data):
    """``active``: the inactive rows with no active neighbour get empty lists, every other
    row its brute-force list; both fill passes agree."""
    import parsph.core.neighbours as nb

    x, n_query, radius = case
    active = np.asarray(data.draw(hnp.arrays(np.bool_, len(x))), dtype=bool)
    ref = brute_force_active(x, n_query, radius, active)
    got = build_csr(x, n_query, radius, active=active)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    gather, disorder = nb._GATHER_MIN_ROWS, nb._GATHER_DISORDER
    try:
        nb._GATHER_MIN_ROWS, nb._GATHER_DISORDER = 0, -1.0
        got = build_csr(x, n_query, radius, active=active.astype(np.uint8))
    finally:
        nb._GATHER_MIN_ROWS, nb._GATHER_DISORDER = gather, disorder
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    if len(x):  # all active: the plain lists
        plain = build_csr(x, n_query, radius)
        every = build_csr(x, n_query, radius, active=np.ones(len(x), dtype=bool))
        assert np.array_equal(plain[1], every[1]) and np.array_equal(plain[0], every[0])


@given(case=point_sets(), data=st.data())
@SETTINGS
def test_near_marks_every_row_within_two_radii_of_an_active_row(case, data):
    """``near``: 1 for every query row within two radii of an active row (the fluid
    step's wall band, parsph.fluid.walls.system_rows), 0 for every row farther than the
    two cells' reach (3 sqrt(3) cells of a radius) on the dense grid; the lists are those
    without it."""
    x, n_query, radius = case
    active = np.asarray(data.draw(hnp.arrays(np.bool_, len(x))), dtype=bool)
    near = np.full(n_query, 7, dtype=np.uint8)
    got = build_csr(x, n_query, radius, active=active, near=near)
    ref = build_csr(x, n_query, radius, active=active)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    assert set(np.unique(near)) <= {0, 1}
    if not active.any() or not n_query:
        return
    pts = np.asarray(x, dtype=float).reshape(len(x), -1)
    gap = np.sqrt(((pts[:n_query, None, :] - pts[None, active, :]) ** 2).sum(axis=2)).min(axis=1)
    assert np.all(near[gap < 2 * radius] == 1)
    from parsph.core.cells import _DENSE_MIN, _DENSE_PER_PARTICLE, _cell_size

    span = pts.max(axis=0) - pts.min(axis=0)
    cell = _cell_size(radius, float(span.max()), 1)
    if np.prod(np.floor(span / cell) + 1.0) <= _DENSE_PER_PARTICLE * len(pts) + _DENSE_MIN:
        # (on the sparse grid of a huge box the cells are not known: every row is near)
        assert np.all(near[gap > 3 * np.sqrt(3) * cell * (1 + 1e-9)] == 0)


def test_active_must_flag_every_row():
    x = np.zeros((5, 2))
    x[:, 0] = np.arange(5)
    with pytest.raises(ValueError, match="one flag per row"):
        build_csr(x, 5, 1.5, active=np.ones(4, dtype=bool))


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_cell_order(dim):
    rng = np.random.default_rng(17)
    x = rng.uniform(-1.0, 1.0, (400, dim))
    perm = cell_order(x, 0.25)
    assert np.array_equal(np.sort(perm), np.arange(400))
    cells = np.floor((x[perm] - x.min(axis=0)) / 0.25).astype(np.int64)
    keys = [tuple(c) for c in cells]
    assert keys == sorted(keys)
    # the lists of the reordered set are the relabelled lists
    ip, ix = build_csr(x, 400, 0.3)
    ip2, ix2 = build_csr(x[perm], 400, 0.3)
    inv = np.argsort(perm)
    for i in range(0, 400, 37):
        a = np.sort(perm[ix2[ip2[inv[i]] : ip2[inv[i] + 1]]])
        assert np.array_equal(a, ix[ip[i] : ip[i + 1]])
    assert cell_order(np.empty((0, dim)), 1.0).shape == (0,)


def test_empty_and_degenerate_inputs():
    for dim in (1, 2, 3):
        indptr, indices = build_csr(np.empty((0, dim)), 0, 1.0)
        assert indptr.tolist() == [0] and indices.shape == (0,) and indices.dtype == np.int32
        x = np.random.default_rng(0).uniform(size=(10, dim))
        indptr, indices = build_csr(x, 0, 1.0)
        assert indptr.tolist() == [0] and indices.size == 0
        indptr, indices = build_csr(x[:1], 1, 1.0)
        assert indptr.tolist() == [0, 0]
        # all points at one place: everyone neighbours everyone else
        indptr, indices = build_csr(np.zeros((5, dim)), 5, 1e-9)
        assert np.array_equal(np.diff(indptr), [4] * 5)
    # radius**2 underflows to 0: nothing is strictly closer
    indptr, indices = build_csr(np.zeros((3, 2)), 3, 1e-200)
    assert indices.size == 0 and indptr.tolist() == [0, 0, 0, 0]


def test_invalid_arguments():
    x = np.zeros((4, 3))
    with pytest.raises(ValueError):
        build_csr(x, 5, 1.0)
    with pytest.raises(ValueError):
        build_csr(x, -1, 1.0)
    for r in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            build_csr(x, 4, r)
    with pytest.raises(ValueError):
        build_csr(np.zeros((4, 4)), 4, 1.0)
    with pytest.raises(ValueError):
        build_csr(np.zeros(4), 4, 1.0)
    bad = np.zeros((4, 2))
    bad[2, 1] = np.nan
    with pytest.raises(ValueError):
        build_csr(bad, 4, 1.0)
    with pytest.raises(ValueError):
        build_csr(np.array([[-1e308, 0.0], [1e308, 0.0]]), 2, 1.0)


def test_pair_helpers():
    indptr = np.array([0, 2, 2, 5], dtype=np.int64)
    assert pair_count(indptr) == 5
    assert row_lengths(indptr).tolist() == [2, 0, 3]
    assert row_of_pairs(indptr).tolist() == [0, 0, 2, 2, 2]


def test_non_contiguous_and_integer_input():
    x = np.arange(30, dtype=np.int64).reshape(10, 3)
    check_against_brute_force(x, 10, 3.0)
    big = np.random.default_rng(3).uniform(size=(50, 6))
    check_against_brute_force(big[:, ::2], 50, 0.3)


# ----------------------------------------------------------------------- eq. (33)


def regular_lattice(dim, n, d):
    g = np.arange(n) * d
    return np.array(list(itertools.product(g, repeat=dim)), dtype=np.float64)


@pytest.mark.parametrize("dim, n", [(2, 24), (3, 12)])
def test_density_of_regular_lattice_interior(dim, n):
    """m = rho d^D, h = 1.2 d: interior density = rho to 1e-3 (paper eq. (33))."""
    d, rho = 0.01, 1800.0
    h = K.smoothing_length(d)
    x = regular_lattice(dim, n, d)
    # shuffle rows: the result must not depend on the row order
    x = x[np.random.default_rng(1).permutation(len(x))]
    m = np.full(len(x), rho * d**dim)
    indptr, indices = build_csr(x, len(x), K.support_radius(h))
    density = density_summation(x, m, indptr, indices, h, dim)
    lo, hi = x.min(axis=0), x.max(axis=0)
    interior = np.all((x - lo > 2 * h) & (hi - x > 2 * h), axis=1)
    assert interior.sum() > 10
    assert np.allclose(density[interior], rho, rtol=1e-3)
    # near a free surface the sum is deficient (fewer neighbours)
    assert density[~interior].min() < 0.8 * rho


def test_density_includes_self_term_and_matches_direct_sum():
    rng = np.random.default_rng(5)
    for dim in (1, 2, 3):
        x = rng.uniform(0.0, 1.0, (300, dim))
        m = rng.uniform(0.5, 2.0, 300)
        h = 0.07
        n_query = 200
        indptr, indices = build_csr(x, n_query, 2 * h)
        out = np.full(n_query, np.nan)
        rho = density_summation(x, m, indptr, indices, h, dim, out=out)
        assert rho is out
        r = np.sqrt(((x[:n_query, None, :] - x[None, :, :]) ** 2).sum(axis=-1))
        ref = (m[None, :] * K.w_array(r, h, dim)).sum(axis=1)  # includes j = i (r = 0)
        assert np.allclose(rho, ref, rtol=1e-12, atol=0)
    # an isolated particle has density m W(0, h)
    one = np.zeros((1, 3))
    rho = density_summation(one, np.array([2.0]), *build_csr(one, 1, 1.0), 0.5, 3)
    assert rho[0] == pytest.approx(2.0 * K.normalisation(0.5, 3))


def test_density_argument_checks():
    x = np.zeros((3, 2))
    indptr, indices = build_csr(x, 3, 1.0)
    with pytest.raises(ValueError):
        density_summation(x, np.ones(3), indptr, indices, 0.5, 3)
    with pytest.raises(ValueError):
        density_summation(x, np.ones(2), indptr, indices, 0.5, 2)
    with pytest.raises(ValueError):
        density_summation(x, np.ones(3), indptr, indices, 0.5, 2, out=np.empty(2))
    empty = density_summation(x, np.ones(3), np.zeros(1, np.int64), indices[:0], 0.5, 2)
    assert empty.shape == (0,)
