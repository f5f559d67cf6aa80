"""Small scenes written by tests (TOML text, so tests exercise the real loader)."""

MOVING_2D = """
[scene]
name = "moving"
description = "two blocks passing through each other over a floor, periodic in x"

[domain]
dim = 2
particle_size = 0.05
lo = [0.0, -0.2]
hi = [2.0, 1.2]
periodic = [true, false]

[run]
end_time = 0.4
mode = "kinematic"
cfl = 0.5

[output]
every = 0.2
progress = false

[materials.sand]
model = "kinematic"
density = 1500.0

[[bodies]]
name = "left"
material = "sand"
shape = "box"
lo = [0.1, 0.0]
hi = [0.9, 0.5]
velocity = [2.0, 0.3]

[[bodies]]
name = "right"
material = "sand"
shape = "polygon"
vertices = [[1.0, 0.0], [1.9, 0.0], [1.9, 0.6], [1.2, 0.4]]
velocity = [-1.5, 0.0]

[[walls]]
name = "floor"
shape = "box"
lo = [0.0, -0.15]
hi = [2.0, 0.0]
"""

MOVING_3D = """
[scene]
name = "moving3d"

[domain]
dim = 3
particle_size = 0.1
lo = [0.0, 0.0, -0.4]
hi = [1.5, 1.0, 1.0]
periodic = [true, true, false]

[run]
end_time = 0.2
mode = "kinematic"
cfl = 0.5

[output]
every = 0.1
progress = false

[materials.rock]
model = "kinematic"
density = 2000.0

[[bodies]]
name = "slab"
material = "rock"
shape = "extruded_polygon"
vertices = [[0.0, 0.0], [1.2, 0.0], [0.0, 0.6]]
extent = [0.0, 1.0]
velocity = [1.0, -0.5, 0.0]

[[walls]]
name = "bed"
shape = "tank"
lo = [0.0, 0.0, 0.0]
hi = [1.5, 1.0, 0.9]
sides = ["bottom"]
"""

#: Gravity of the 2D scenes (m/s^2).
G_2D = [0.0, -9.81]


# --------------------------------------------------------------------- scene builder
# Scenes written from Python values: the TOML text is still what the loader reads.


def toml_value(value):
    """One TOML value: a bool, a number (``repr`` of the float: round-trips), a string or
    a (nested) list of them."""
    import numbers

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))
    return "[" + ", ".join(toml_value(v) for v in value) + "]"


def toml_text(**tables):
    """TOML text of ``tables``, in the order given: a dict is a table, its dict values
    sub-tables (``materials={"water": {...}}`` is ``[materials.water]``); a list of dicts
    is an array of tables (``bodies=[...]``, one ``[[bodies]]`` each). Starts with a
    newline, so that it can be appended to a scene's text."""
    lines = [""]

    def emit(name, table, array):
        plain = {k: v for k, v in table.items() if not isinstance(v, dict)}
        if plain or len(plain) == len(table):  # a header for its keys, or an empty table
            lines.append(f"[[{name}]]" if array else f"[{name}]")
        lines.extend(f"{k} = {toml_value(v)}" for k, v in plain.items())
        for k, v in table.items():
            if isinstance(v, dict):
                emit(f"{name}.{k}", v, False)

    for name, value in tables.items():
        for item in value if isinstance(value, list) else [value]:
            emit(name, item, isinstance(value, list))
    return "\n".join(lines) + "\n"


def scene_text(name, d, lo, hi, end, every=None, *, g=None, description=None,
               periodic=None, run=None, output=None, progress=False, **tables):
    """A scene's TOML: ``[scene]``, ``[domain]`` (``dim`` the length of ``lo``), ``[run]``
    with ``end_time`` and ``run``'s keys, ``[output]`` with ``every`` (``end`` unless
    given), ``progress`` (left out when None) and ``output``'s keys, ``[gravity]`` when
    ``g`` is given; then ``tables`` (``materials``, ``bodies``, ... as :func:`toml_text`)."""
    scene = {"name": name} if description is None else {"name": name, "description": description}
    domain = {"dim": len(lo), "particle_size": d, "lo": lo, "hi": hi}
    if periodic is not None:
        domain["periodic"] = periodic
    out = {"every": end if every is None else every}
    if progress is not None:
        out["progress"] = progress
    head = {"scene": scene, "domain": domain, "run": {"end_time": end, **(run or {})},
            "output": {**out, **(output or {})}}
    if g is not None:
        head["gravity"] = {"g": g}
    return toml_text(**head, **tables)


def water(viscosity=1.0e-6, density=1000.0):
    """A Newtonian water material."""
    return {"model": "newtonian", "density": density, "viscosity": viscosity}


def hencky(density, young_modulus, poisson_ratio=0.3, **keys):
    """An elastic (Hencky) material."""
    return {"model": "hencky", "density": density, "young_modulus": young_modulus,
            "poisson_ratio": poisson_ratio, **keys}


def box(name, material, lo, hi, **keys):
    """A box body (``velocity`` and the like in ``keys``)."""
    return {"name": name, "material": material, "shape": "box", "lo": lo, "hi": hi, **keys}


def wall(name, lo, hi, shape="box", **keys):
    """A box wall (or another ``shape`` with ``lo`` and ``hi``)."""
    return {"name": name, "shape": shape, "lo": lo, "hi": hi, **keys}


def tank(name, lo, hi, sides=("left", "right", "bottom"), **keys):
    """A tank wall with the given ``sides``."""
    return wall(name, lo, hi, "tank", sides=list(sides), **keys)


def held(lo, hi, name="hold"):
    """A constraint holding the particles in [lo, hi] at rest."""
    return {"name": name, "lo": lo, "hi": hi, "velocity": [0.0] * len(lo)}


def initial(name, profile, lo, hi, **keys):
    """An initial-velocity constraint (``rigid_rotation``: ``centre``, ``omega``;
    ``uniform``: ``velocity``)."""
    return {"name": name, "kind": "initial", "profile": profile, "lo": lo, "hi": hi, **keys}


def water_around(block_lo, block_hi, water_lo, water_hi,
                 names=("w_left", "w_right", "w_below", "w_above", "block")):
    """Box bodies of ``water`` filling [water_lo, water_hi] around a 2D ``block`` body at
    [block_lo, block_hi]: left, right, below and (when the block's top is below the
    water's) above it, then the block."""
    (x0, y0), (x1, y1), (bx0, by0), (bx1, by1) = water_lo, water_hi, block_lo, block_hi
    bodies = [box(names[0], "water", [x0, y0], [bx0, y1]),
              box(names[1], "water", [bx1, y0], [x1, y1]),
              box(names[2], "water", [bx0, y0], [bx1, by0])]
    if by1 < y1:
        bodies.append(box(names[3], "water", [bx0, by1], [bx1, y1]))
    return bodies + [box(names[4], "block", block_lo, block_hi)]


def write(tmpdir, text, name="scene.toml"):
    import os

    path = os.path.join(tmpdir, name)
    with open(path, "w") as fh:
        fh.write(text)
    return path


def write_shared(comm, tmpdir, text, name="scene.toml"):
    """Write ``text`` to ``tmpdir/name`` and return its path on every rank: rank 0 writes
    (the ranks of ``comm`` share ``tmpdir``); with ``comm`` None this process writes."""
    if comm is None:
        return write(tmpdir, text, name)
    return comm.bcast(write(tmpdir, text, name) if comm.rank == 0 else None)


def load_shared(comm, tmpdir, text, overrides=(), name="scene.toml"):
    """:func:`write_shared`, then load the scene with ``overrides`` on every rank."""
    from parsph.scene.loader import load_scene

    return load_scene(write_shared(comm, tmpdir, text, name), list(overrides))


def stats_rows(out):
    """The rows of a run directory's stats.csv (dicts of strings)."""
    import csv
    import os

    with open(os.path.join(out, "stats.csv")) as fh:
        return list(csv.DictReader(fh))


def count_kept_strays(monkeypatch, layout=None):
    """Spy on lazy migration (``parsph.step.refresh._keep_strays``): the returned list
    gets, per call (of a context in ``layout``, default any), the number of rows that
    left their rank's sub-box and were kept."""
    import parsph.step.refresh as refresh_module

    kept = []
    keep = refresh_module._keep_strays

    def spy(ctx, x, dest):
        before = int((dest != ctx.comm.rank).sum())
        result = keep(ctx, x, dest)
        if layout is None or ctx.layout == layout:
            kept.append(before - int((dest != ctx.comm.rank).sum()))
        return result

    monkeypatch.setattr(refresh_module, "_keep_strays", spy)
    return kept


def by_id(frame):
    """A frame's fields ordered by global id."""
    import numpy as np

    order = np.argsort(frame["id"])
    return {k: v[order] for k, v in frame.items()}


def last_frame(out):
    """The last frame of a run directory, ordered by global id."""
    import os

    from parsph.io import read_frame

    return by_id(read_frame(os.path.join(out, "particles.h5"), "last"))


def first_and_last(out):
    """The first and last frames of a run directory, ordered by global id."""
    import os

    from parsph.io import read_frame

    h5 = os.path.join(out, "particles.h5")
    return by_id(read_frame(h5, 0)), by_id(read_frame(h5, "last"))


def run_on_one_and_two(comm, scene, tmpdir):
    """The keystone comparison: run ``scene`` on rank 0 alone, then on all ranks.

    Returns the two run directories (``tmpdir/one``, ``tmpdir/two``); compare their
    frames by global id on rank 0. The ranks agree after each run whether it failed
    (:func:`agree_on_failure`): when rank 0's one-rank run raises, every rank raises
    instead of the others waiting for rank 0 in the first collective of the two-rank run.
    """
    import os

    from parsph.step.pipeline import needs_petsc, plan
    from parsph.step.run import run

    if needs_petsc(plan(scene), scene):  # PetscInitialize is collective on the world: all ranks now
        import solvers

        solvers.init([])
    one_dir, two_dir = os.path.join(tmpdir, "one"), os.path.join(tmpdir, "two")
    alone_on_rank_zero(comm, lambda one: run(scene, one_dir, comm=one, progress=False))
    error = None
    try:
        run(scene, two_dir, comm=comm, progress=False)
    except Exception as exc:  # noqa: BLE001 - raised on every rank below
        error = exc
    agree_on_failure(comm, error)
    return one_dir, two_dir


def alone_on_rank_zero(comm, fn):
    """Collective: ``fn(one)`` on rank 0, ``one`` a communicator of rank 0 alone; its
    result there, None elsewhere. If ``fn`` raises, every rank raises
    (:func:`agree_on_failure`), so no rank goes on into a collective rank 0 never joins."""
    from mpi4py import MPI

    one = comm.Split(0 if comm.rank == 0 else MPI.UNDEFINED, comm.rank)
    result = error = None
    if comm.rank == 0:
        try:
            result = fn(one)
        except Exception as exc:  # noqa: BLE001 - raised on every rank below
            error = exc
        finally:
            one.Free()
    agree_on_failure(comm, error)
    return result


def agree_on_failure(comm, error):
    """Collective: if any rank has an ``error``, raise on every rank, a failing rank its
    own error (its traceback), the others the lowest failing rank's type and message
    (:func:`decomposition.comm.raise_if_any`)."""
    from decomposition.comm import raise_if_any

    try:
        raise_if_any(comm, error)
    except Exception:
        if error is not None:
            raise error from None
        raise


def assert_agree_by_id(one, two, x_tol=1e-6, v_tol=1e-4):
    """The last frames of two runs (directories) have the same particles, phases and,
    to the tolerances (m, m/s), positions and velocities by global id; returns them."""
    import numpy as np

    a, b = last_frame(one), last_frame(two)
    assert np.array_equal(a["id"], b["id"])
    assert np.array_equal(a["phase"], b["phase"])
    assert np.abs(a["x"] - b["x"]).max() < x_tol
    assert np.abs(a["v"] - b["v"]).max() < v_tol
    return a, b


#: A row of five Bingham particles sliding on a floor at 1 m/s, all on the free surface.
LONE_ROW = scene_text(
    "lone_row", 0.05, [-0.5, -0.3], [3.0, 1.0], 0.6, 0.05, g=G_2D,
    description="a row of five Bingham particles sliding on a floor at 1 m/s, all on the "
                "free surface",
    materials={"debris": {  # slope_failure's debris (Table 2)
        "model": "bingham", "density": 1655.0, "viscosity": 1.0e-3, "viscosity_max": 1.0e4,
        "cohesion": 10.0, "friction_angle": 19.5}},
    bodies=[box("row", "debris", [0.0, 0.0], [0.25, 0.05], velocity=[1.0, 0.0])],
    walls=[wall("floor", [-0.5, -0.15], [3.0, 0.0])])


def dense_system(kernel, *args, n_points, dim=1, capacity=None, tail=()):
    """Run a CSR kernel (``parsph.fluid.viscous.viscous_csr``, ``parsph.fluid.ppe.ppe_csr``) on
    rows numbered from 0 and return its matrix dense, with the right-hand side; checks
    on the way that every row's columns are sorted and distinct and, given
    ``capacity`` (``assembly.csr_capacity``), that the kernel wrote nothing past it.
    ``tail``: arguments after the CSR arrays."""
    import numpy as np

    n = n_points * dim
    cap = dim * dim * (n_points * n_points + n_points) if capacity is None else capacity
    guard = 64
    ptr = np.zeros(n + 1, dtype=np.int32)
    cols = np.full(cap + guard, -7, dtype=np.int32)
    vals = np.full(cap + guard, -7.0)
    nnz, rhs = kernel(*args, 0, ptr, cols, vals, *tail)
    assert ptr[-1] == nnz <= cap and np.all(np.diff(ptr) >= 0)
    assert np.all(cols[cap:] == -7) and np.all(vals[cap:] == -7.0), "wrote past the capacity"
    A = np.zeros((n, n))
    for r in range(n):
        c = cols[ptr[r]:ptr[r + 1]]
        assert np.all(np.diff(c) > 0), f"row {r}: columns {c} not sorted and distinct"
        A[r, c] = vals[ptr[r]:ptr[r + 1]]
    return A, rhs


def gather_particles(comm, fields):
    """Every rank's (id, x, phase) of ``fields``, sorted by global id (all ranks)."""
    import numpy as np

    allf = comm.allgather({k: fields[k] for k in ("id", "x", "phase")})
    ids = np.concatenate([f["id"] for f in allf])
    order = np.argsort(ids)
    return ids[order], np.concatenate([f["x"] for f in allf])[order], \
        np.concatenate([f["phase"] for f in allf])[order]


def pvbatch(*args, timeout=300):
    """Run Debian's ``pvbatch`` with ``args`` under ``xvfb-run`` (if installed), outside
    the MPI job of the test (a clean MPI environment); returns the CompletedProcess.

    An X server that does not come up, or that pvbatch cannot connect to ("bad X server
    connection": a display an old server still held), is retried twice more, each time
    on another display number picked at random and after a pause; nothing else is
    retried. Three immediate retries on the same display had all failed once in CI."""
    import os
    import random
    import re
    import shutil
    import subprocess
    import time

    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("OMPI_", "PMIX_", "PMI_", "OPAL_", "HYDRA_"))}
    xvfb = shutil.which("xvfb-run")
    for attempt in range(3):
        display = ["-n", str(random.randint(100, 9999))] if attempt else []
        cmd = ([xvfb, "-a", *display] if xvfb else []) + [shutil.which("pvbatch"), *args]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
        if r.returncode == 0 or not re.search(r"X server|display", r.stderr, re.I):
            return r
        time.sleep(2.0 * (attempt + 1))
    return r


def energy_balance(rows):
    """A run's energy balance from its stats rows (docs/energy.md): ``(rise, gain)``,
    the largest rise of E in a step and over any stretch of steps, each over the peak
    kinetic energy (the last row's running ``energy_rise_max``, ``energy_gain_max``)."""
    return float(rows[-1]["energy_rise_max"]), float(rows[-1]["energy_gain_max"])


def assert_energy_balance(rows, rise, gain, what="the run"):
    """The run's energy balance rises by at most ``rise`` of its peak kinetic energy in
    a step and ``gain`` over any stretch of steps; the message names the worst step."""
    got = energy_balance(rows)
    worst = max(rows, key=lambda r: float(r["energy_rise"]))
    message = (f"{what}: E rose by {got[0]:.3g} of the peak kinetic energy in a step (the "
               f"largest at step {worst['step']}, t = {worst['time']} s) and {got[1]:.3g} "
               f"over a stretch of steps; allowed {rise:g} and {gain:g}")
    print(f"{what}: energy balance rise {got[0]:.3g}, gain {got[1]:.3g} of the peak kinetic "
          f"energy")
    assert got[0] <= rise and got[1] <= gain, message
