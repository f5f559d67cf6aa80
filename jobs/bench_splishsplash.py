"""Benchmark: the IISPH dam break in 3D side by side with SPlisHSPlasH.

Simulates the collapse of a water column a = 0.146 m wide, 2a high and a deep (water
rho = 1000 kg/m^3, nu = 1e-6 m^2/s) against the left wall of a box 4a long, a deep and
0.35 m high, to the same end time, with the same fluid particles (n x n x 2n at spacing
d = a / n, centres at (k + 1/2) d in both codes) with

- parsph (``parsph run`` of the 3D scene this job writes into its work directory: the
  ``dam_break`` scene with ``dim = 3``, a ``tank`` wall of 3 layers on the left, right,
  front, back and bottom; GMRES + BoomerAMG on the PPE) on ``--ranks`` ranks, once per
  PPE tolerance of ``--density-error``: by default at SPlisHSPlasH's own (``peer``: its
  ``IISPH.maxError`` as ``fluid.ppe_density_error``, which parsph applies to the RMS
  density error, a stricter norm than SPlisHSPlasH's mean) and at ``0`` (parsph's
  default, ``fluid.ppe_rtol`` = 1e-8 alone), and
- SPlisHSPlasH 2.19 (``pysplishsplash`` from PyPI; C++ with OpenMP, float32): IISPH
  (``simulationMethod`` 3, relaxed Jacobi to ``IISPH.maxError`` = 0.01 % mean density
  error, 2-100 sweeps), standard CFL step with ``cflFactor`` 0.25, standard viscosity
  nu, the box a static rigid body (``UnitBox.obj`` of the wheel's data) with Akinci et
  al. (2012) boundary particles sampled on it, its surface ``--wall-offset`` d (0.6)
  outside parsph's wall planes (:func:`boundary_box`); on ``--threads`` OpenMP threads
  (default one),

alternately, ``--repeats`` times each (noise between identical runs reaches 25 %), and
prints one row per code, core count and tolerance (medians): fluid and total particles,
steps, run wall time, fluid particle-steps/s per core, pressure iterations per step, the
largest density error parsph's solves left (``density_error_max``, relative), where the
flow is at the end (:func:`flow_extent`: ``front``, the largest x of a fluid particle;
``front_p999``, the x that 0.1 % of the fluid is beyond; ``top``, the largest height; m)
and the two codes' flows against each other (``front_p999_vs_splishsplash``, ``top_vs_
splishsplash``: relative differences; the ratios of cost mean little unless these are
small), the whole process's peak RSS (``peak_rss_mib_max``, the largest rank's, and
``bytes_per_particle_peak_rss``, every rank's over all particles: parsph's ``done:``
line, SPlisHSPlasH's ``ru_maxrss``), SPlisHSPlasH's density at its first step
(``initial_density_max``, the largest, and ``initial_density_floor``, the mean of the
fluid's lowest layer, over rho0: the boundary's placement, below), and the ratios parsph /
SPlisHSPlasH of the cost of a fluid particle-step on one core (``ratio_vs_splishsplash``;
below 1: parsph is cheaper) and of the core-seconds to the end time
(``core_time_ratio_vs_splishsplash``; the two codes take different steps).

Where the peer's wall goes (docs/benchmarks.md, "SPlisHSPlasH, the same flow"). An
Akinci boundary is one layer of particles; the fluid's first layer feels it as a wall
only approximately. With the box through the centres of parsph's first wall layer (0.5 d
outside its wall planes, the fluid's first layer one d from the boundary particles) the
peer's fluid starts over-dense where it touches the box: 1.063 rho0 on the floor, 1.165
in the corners, at n = 16. Its PPE removes that density error within its first step, a
kick that grows as 1 / dt: the column rose 4.6 mm in its first 0.04 s while parsph's fell,
the toe shot ahead, the front at 0.1 s was 0.264 m against parsph's 0.239, and at
``cflFactor`` 0.1 the run blew up. At 0.6 d the first layer starts at 0.999 rho0 (corners
0.988); the two flows then agree (n = 16: ``front_p999`` 0.2392 against parsph's 0.2368,
``top`` 0.2504 against 0.2471; 0.2357 and 0.2505 at ``cflFactor`` 0.1) and the peer's
step no longer explodes at a smaller ``cflFactor``. ``initial_density_max`` shows what a
placement does. (SPlisHSPlasH's volume maps, Bender et al. 2019, were tried and left out:
with the box at parsph's wall planes their first fluid layer started at 2.4 rho0, at half
a d further out at 1.2, finer maps alike.)

Run wall time, the same rule for both codes: from the end of step 1 to the end of step N,
scaled by N / (N - 1), the N steps at the mean cost of steps 2..N. SPlisHSPlasH samples
its boundary inside its run call, before the first step, which
is why step 1 is left out; parsph's ends of steps are the ``elapsed_s`` column of its
stats.csv (rank 0's clock; every per-step cost counted: stats, checks, partition). parsph's
own timer ("done ... s wall": particle build, output and steps) is printed as
``own_timer_s``, and both processes' wall times as ``process_s``.

SPlisHSPlasH is installed from PyPI (a cp311 manylinux wheel) into a scratch venv outside
the repository (``--splishsplash-venv``, default under the temp dir) if missing. The
wheel's bundled libGLdispatch clashes with the system's (importing it segfaults), so the
system's ``libGLdispatch.so.0`` is preloaded for it. Default size: ~24,000 fluid particles
(n = 23: 24,334), to t = 0.1 s:

    source scripts/env.sh
    .venv/bin/python jobs/bench_splishsplash.py --fluid-particles 24000 --end-time 0.1 \\
        --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import csv
import ctypes.util
import glob
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import bytes_per_particle, mpirun_parsph, record, worker_line  # noqa: E402

A, RHO, NU, G = 0.146, 1000.0, 1.0e-6, 9.81  # as parsph/scenes/dam_break.toml
TANK_LENGTH, TANK_DEPTH, TANK_HEIGHT = 4.0 * A, A, 0.35
WALL_LAYERS = 3  # parsph's tank: ceil(2h / d) with h = 1.2 d
WALL_OFFSET = 0.6  # SPlisHSPlasH's box outside parsph's wall planes (d; the docstring)
BENCHMARK = "iisph_dam_break_3d_vs_splishsplash"
RESULT_TAG = "SPLISHSPLASH_RESULT "

PARSPH_SCENE = """# 3D dam break, written by parsph's jobs/bench_splishsplash.py
[scene]
name = "dam_break_3d"
description = "water column a wide, 2a high, a deep collapsing in a tank 4a long, a deep"

[domain]
dim = 3
particle_size = {d!r}       # a / {n}
lo = {lo}
hi = {hi}

[run]
end_time = {end!r}

[output]
every = 1.0e9               # a frame at the start and at the last step only

[gravity]
g = [0.0, 0.0, {g!r}]

[materials.water]
model = "newtonian"
density = {rho!r}
viscosity = {nu!r}

[[bodies]]
name = "column"
material = "water"
shape = "box"
lo = [0.0, 0.0, 0.0]
hi = [{a!r}, {a!r}, {h!r}]

[[walls]]
name = "tank"
shape = "tank"
lo = [0.0, 0.0, 0.0]
hi = [{length!r}, {depth!r}, {height!r}]
sides = ["left", "right", "front", "back", "bottom"]
slip = "no_slip"
"""

SPLISHSPLASH_SCRIPT = """# SPlisHSPlasH 3D dam break, written by parsph's jobs/bench_splishsplash.py
# usage: python THIS SCENE.json OUTPUT_DIR END_TIME '[[xlo, ylo, zlo], [xhi, yhi, zhi]]'
import json, os, resource, sys, time

import pysplishsplash as sph

scene, out, end, (lo, hi) = sys.argv[1], sys.argv[2], float(sys.argv[3]), json.loads(sys.argv[4])
t0 = time.perf_counter()
base = sph.Exec.SimulatorBase()
base.init(sceneFile=scene, outputDir=out, useGui=False, initialPause=False, stopAt=end)
base.initSimulation()
sim = sph.Simulation.getCurrent()
ts = sim.getTimeStep()
sweeps_of = getattr(ts, "getNumIterations", lambda: -1)
fluid = sim.getFluidModel(0)
stamps, sweeps, first = [], [], {}


def after_step():
    stamps.append(time.perf_counter())
    sweeps.append(sweeps_of())
    if len(stamps) == 1:  # the density the boundary's placement gave (out of the clock)
        rho0, d = fluid.getDensity0(), 2.0 * sim.getParticleRadius()
        rho = [fluid.getDensity(i) / rho0 for i in range(fluid.numActiveParticles())]
        floor = [r for i, r in enumerate(rho) if float(fluid.getPosition(i)[1]) < d]
        first.update(initial_density_max=max(rho), initial_density_floor=sum(floor) / len(floor))
        stamps[0] = time.perf_counter()


base.setTimeStepCB(after_step)
t1 = time.perf_counter()
base.runSimulation()
t2 = time.perf_counter()
x = [[float(c) for c in fluid.getPosition(i).ravel()] for i in range(fluid.numActiveParticles())]
boundary = sim.getValueInt(sim.BOUNDARY_HANDLING_METHOD)
walls = sum(sim.getBoundaryModel(i).numberOfParticles()
            for i in range(sim.numberOfBoundaryModels())) if boundary == 0 else 0
print("SPLISHSPLASH_RESULT " + json.dumps(dict(
    version=getattr(sph, "__version__", ""), method=sim.getValueInt(sim.SIMULATION_METHOD),
    boundary=boundary, cfl=sim.getValueFloat(sim.CFL_FACTOR),
    max_error=ts.getValueFloat(ts.MAX_ERROR) if hasattr(ts, "MAX_ERROR") else None,
    radius=sim.getParticleRadius(), fluid=len(x), boundary_particles=walls,
    steps=len(stamps), t=sph.TimeManager.getCurrent().getTime(), init_s=t1 - t0,
    first_step_s=(stamps[0] - t1) if stamps else None,
    later_steps_s=(stamps[-1] - stamps[0]) if stamps else None, run_call_s=t2 - t1,
    sweeps_mean=sum(sweeps) / max(len(sweeps), 1), sweeps_max=max(sweeps, default=0),
    x=[[round(c, 7) for c in p] for p in x], **first,
    peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    outside=sum(any(p[k] < lo[k] or p[k] > hi[k] for k in range(3)) for p in x))), flush=True)
# skip the C++ teardown (timing tables; a crash there would only hide the result)
os._exit(0)
"""


def column_divisions(fluid_particles=None, spacing=None) -> int:
    """n, the particles across the column (n x n x 2n fluid particles at d = a / n), from
    an approximate fluid particle count or a spacing (m; rounded to a / n)."""
    n = round(A / spacing) if spacing else round((fluid_particles / 2.0) ** (1.0 / 3.0))
    if n < 4:
        raise SystemExit(f"a column of {n} x {n} x {2 * n} particles is too coarse for a dam "
                         f"break; ask for at least 128 fluid particles (--fluid-particles) or "
                         f"a spacing of at most {A / 4:.4g} m (--spacing)")
    return int(n)


def parsph_scene(n: int, end: float) -> str:
    """The parsph scene (TOML text) of the 3D dam break at d = a / n to ``end`` (s): x along
    the tank, y across it, z up."""
    d = A / n
    margin = 0.1 + (WALL_LAYERS + 1) * d
    lo = [-margin] * 3
    hi = [TANK_LENGTH + margin, TANK_DEPTH + margin, TANK_HEIGHT + margin]
    return PARSPH_SCENE.format(d=d, n=n, lo=lo, hi=hi, end=end, g=-G, rho=RHO, nu=NU, a=A,
                               h=2 * A, length=TANK_LENGTH, depth=TANK_DEPTH,
                               height=TANK_HEIGHT)


def fluid_block(n: int):
    """``start`` and ``end`` of a SPlisHSPlasH ``FluidBlock`` (x along the tank, y up, z
    across) whose particles sit where parsph's do: (k + 1/2) d, k < n (2n upward).

    SPlisHSPlasH (``denseMode`` 0) puts them at ``start + j 2r``, j = 1 .. round((end -
    start) / 2r) - 1 on each axis (:func:`block_axes`), so the block reaches d/2 beyond
    the column on each side."""
    d = A / n
    return [-0.5 * d] * 3, [(n + 0.5) * d, (2 * n + 0.5) * d, (n + 0.5) * d]


def block_axes(start, end, radius):
    """The particle coordinates along each axis of a SPlisHSPlasH ``FluidBlock``
    (``denseMode`` 0, as its ``SimulatorBase::createFluidBlocks``)."""
    diam = 2.0 * radius
    return [[s + diam * j for j in range(1, int(round((e - s) / diam)) - 1 + 1)]
            for s, e in zip(start, end)]


def boundary_box(n: int, wall_offset: float = WALL_OFFSET):
    """Inner corners (x, y up, z) of SPlisHSPlasH's box: its surface, on which the Akinci et
    al. (2012) boundary particles are sampled, ``wall_offset`` d outside parsph's wall
    planes (0.5: through the centres of parsph's first wall layer; 0.6, the default: where
    the peer's fluid starts at rest density, the module's docstring)."""
    o = wall_offset * A / n
    return [-o, -o, -o], [TANK_LENGTH + o, TANK_HEIGHT, TANK_DEPTH + o]


def flow_extent(x, up: int) -> dict:
    """Where a flow is: ``front``, the largest x (axis 0) of a fluid particle; ``front_p999``,
    the x that 0.1 % of the fluid is beyond (a leading particle or two that left the flow do
    not move it); ``top``, the largest coordinate on axis ``up`` (m)."""
    import numpy as np

    x = np.asarray(x, dtype=float)
    return {"front": float(x[:, 0].max()), "front_p999": float(np.quantile(x[:, 0], 0.999)),
            "top": float(x[:, up].max())}


def splishsplash_scene(n: int, mesh: str, overrides=(), wall_offset=WALL_OFFSET) -> dict:
    """The SPlisHSPlasH scene (JSON data) of the 3D dam break at particleRadius d / 2;
    ``overrides``: ``KEY=VALUE`` of its ``Configuration`` (``IISPH.maxError=0.1``; the
    value read as JSON, else as a string)."""
    d = A / n
    lo, hi = boundary_box(n, wall_offset)
    start, end = fluid_block(n)
    config = {"particleRadius": 0.5 * d, "simulationMethod": 3, "gravitation": [0.0, -G, 0.0],
              "timeStepSize": 0.001, "cflMethod": 1, "cflFactor": 0.25,
              "cflMaxTimeStepSize": 0.005, "boundaryHandlingMethod": 0,
              "enablePartioExport": False, "enableVTKExport": False,
              "IISPH": {"minIterations": 2, "maxIterations": 100, "maxError": 0.01}}
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"--peer-set {item!r}: give KEY=VALUE (e.g. cflFactor=0.5)")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        *path, last = key.split(".")
        table = config
        for part in path:
            table = table.setdefault(part, {})
        table[last] = value
    return {
        "Configuration": config,
        "Materials": [{"id": "Fluid", "density0": RHO, "viscosityMethod": 1,
                       "Standard viscosity": {"viscosity": NU}}],
        "RigidBodies": [{
            "geometryFile": mesh, "translation": [0.5 * (l + h) for l, h in zip(lo, hi)],
            "scale": [h - l for l, h in zip(lo, hi)], "rotationAxis": [1, 0, 0],
            "rotationAngle": 0, "isDynamic": False, "isWall": True, "samplingMode": 0,
            "mapInvert": True, "mapThickness": 0.0,
            "mapResolution": [max(8, round((h - l) / (2.0 * d))) for l, h in zip(lo, hi)]}],
        "FluidBlocks": [{"denseMode": 0, "start": start, "end": end,
                         "translation": [0.0, 0.0, 0.0], "scale": [1, 1, 1]}],
    }


def density_errors(text: str, iisph: dict) -> list:
    """parsph's PPE tolerances of ``--density-error`` (``fluid.ppe_density_error``, a
    relative density error): numbers, ``peer`` for SPlisHSPlasH's ``maxError`` (a
    percentage, so / 100), 0 for ``fluid.ppe_rtol`` alone."""
    out = []
    for item in text.split(","):
        item = item.strip()
        try:
            eta = float(iisph["maxError"]) / 100.0 if item == "peer" else float(item)
        except (TypeError, ValueError):
            sys.exit(f"--density-error {text!r}: give numbers in [0, 1), or 'peer', separated "
                     f"by commas (e.g. peer,1e-6,0)")
        if not 0.0 <= eta < 1.0:
            sys.exit(f"--density-error {text!r}: {eta:g} is not in [0, 1)")
        out.append(eta)
    return out


def cost_ratio(parsph_rate: float, peer_rate: float) -> float:
    """parsph's cost of a fluid particle-step on one core over SPlisHSPlasH's, from their
    fluid particle-steps/s per core (below 1: parsph is cheaper)."""
    return peer_rate / parsph_rate


def ensure_splishsplash(venv, python):
    """The python of a scratch venv with pysplishsplash, installing it there from PyPI if
    missing, and the wheel's ``UnitBox.obj``."""
    py = os.path.join(venv, "bin", "python")
    if not glob.glob(os.path.join(venv, "lib", "python3*", "site-packages", "pysplishsplash*")):
        print(f"# installing pysplishsplash into {venv} (a wheel, ~1 minute)", file=sys.stderr,
              flush=True)
        try:
            subprocess.run([python, "-m", "venv", venv], check=True)
            subprocess.run([os.path.join(venv, "bin", "pip"), "install", "-q", "pysplishsplash"],
                           check=True)
        except (OSError, subprocess.CalledProcessError) as exc:
            sys.exit(f"could not install SPlisHSPlasH into {venv} ({exc}): `{python} -m venv` "
                     f"and `pip install pysplishsplash` need PyPI and a Python its wheel is "
                     f"built for (cp311, manylinux x86_64); give a Python 3.11 with "
                     f"--venv-python, or a venv that has pysplishsplash with "
                     f"--splishsplash-venv")
    meshes = (glob.glob(os.path.join(venv, "bin", "data", "models", "UnitBox.obj"))
              or glob.glob(os.path.join(venv, "**", "UnitBox.obj"), recursive=True))
    if not meshes:
        sys.exit(f"no UnitBox.obj in {venv}: the pysplishsplash wheel ships it in its data "
                 f"(bin/data/models); reinstall it (remove {venv} and run again)")
    return py, meshes[0]


def peer_env(threads):
    """The environment of a SPlisHSPlasH run: no MPI or Python variables of this job,
    ``threads`` OpenMP threads, the system's libGLdispatch preloaded."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("OMPI_", "PMIX_", "OPAL_", "PRTE_", "HYDRA_", "PMI_", "PYTHON"))}
    env["OMP_NUM_THREADS"] = str(threads)
    gl = ctypes.util.find_library("GLdispatch")  # a soname: ld.so finds the system's
    if gl:
        env["LD_PRELOAD"] = " ".join(x for x in (gl, env.get("LD_PRELOAD", "")) if x)
    else:
        print("# warning: no system libGLdispatch.so.0 to preload; importing pysplishsplash "
              "may segfault (Debian: apt-get install libglvnd0)", file=sys.stderr, flush=True)
    return env


def run_splishsplash(py, work, tag, scene, end, threads, n, wall_offset):
    """One SPlisHSPlasH run of ``scene`` (JSON data, its box ``wall_offset`` d outside
    parsph's wall planes) in ``work``; its figures."""
    path = os.path.join(work, f"splishsplash_{tag}.json")
    with open(path, "w") as fh:
        json.dump(scene, fh, indent=1)
    script = os.path.join(work, "dam_break_3d_splishsplash.py")
    d = A / n
    lo, hi = boundary_box(n, wall_offset)
    box = [[c - d for c in lo], [c + d for c in hi]]  # a fluid particle beyond: escaped
    cmd = [py, script, path, os.path.join(work, f"splishsplash_{tag}"), repr(end),
           json.dumps(box)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=work, env=peer_env(threads), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode:
        hint = (" (a segfault: is the system's libGLdispatch.so.0 preloaded?)"
                if proc.returncode == -11 else "")
        sys.exit(f"SPlisHSPlasH failed ({proc.returncode}){hint}: {' '.join(cmd)}\n"
                 f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    what = f"SPlisHSPlasH run ({script} on {path})"
    text = worker_line(proc.stdout, RESULT_TAG, what)
    try:
        res = json.loads(text)
    except json.JSONDecodeError:
        sys.exit(f"{what}: its {RESULT_TAG.strip()} line is not JSON: {text[:500]!r}")
    if res["method"] != 3:
        sys.exit(f"{what}: simulationMethod is {res['method']}, not 3 (IISPH): check --peer-set")
    if res["outside"]:
        print(f"# warning: {res['outside']} SPlisHSPlasH fluid particles left the box "
              f"(lower its cflFactor: --peer-set cflFactor=0.1)", file=sys.stderr, flush=True)
    steps = res["steps"]
    run_s = steps_2_to_n(res["later_steps_s"], steps, f"{what}, to t = {res['t']:.4g} s")
    return dict(code="splishsplash", cores=threads, fluid=res["fluid"],
                particles=res["fluid"] + res["boundary_particles"], steps=steps,
                t_end=res["t"], run_s=run_s, process_s=wall,
                pressure_iterations=res["sweeps_mean"], pressure_iterations_max=res["sweeps_max"],
                peak_rss_mib=[res["peak_rss_mib"]],
                initial_density_max=res["initial_density_max"],
                initial_density_floor=res["initial_density_floor"],
                **flow_extent(res.pop("x"), up=1), info=res)


def run_parsph(ranks, scene, out, extra=()):
    """One parsph run of the scene file ``scene`` into ``out``, timed as SPlisHSPlasH is
    (:func:`steps_time`); its other figures are read later by :func:`read_parsph`."""
    res = dict(code="parsph", cores=ranks, out=out, **mpirun_parsph(ranks, scene, out, extra))
    res["own_timer_s"] = res["run_s"]
    res["run_s"] = steps_time(os.path.join(out, "stats.csv"))
    return res


def steps_time(stats_csv):
    """The N steps of a parsph run at the mean cost of steps 2..N (s), from the ``elapsed_s``
    column of its stats.csv (read with the csv module: no MPI library is loaded here)."""
    with open(stats_csv, newline="") as fh:
        ends = [float(r["elapsed_s"]) for r in csv.DictReader(fh)]
    return steps_2_to_n(ends[-1] - ends[0] if ends else 0.0, len(ends), stats_csv)


def steps_2_to_n(span, steps, what):
    """Both codes' rule: the ``steps`` steps at the mean cost of steps 2..N, from ``span``,
    the wall time from the end of step 1 to the end of the last (s); exits naming
    ``what`` if there are fewer than two steps."""
    if steps < 2:
        sys.exit(f"{what}: {steps} step(s); its time is taken from steps 2..N: give a longer "
                 f"--end-time")
    return span * steps / (steps - 1)


def read_parsph(res):
    """Add the particle counts, PPE iterations and the end front of a parsph run."""
    import numpy as np

    from parsph.core.particles import PHASE_FLUID
    from parsph.io import read_frame, read_stats

    stats = read_stats(os.path.join(res["out"], "stats.csv"))
    res.update(particles=int(stats["n_particles"][0]), fluid=int(stats["n_fluid"][0]),
               pressure_iterations=float(np.median(stats["ppe_iterations"])),
               pressure_iterations_max=int(np.max(stats["ppe_iterations"])),
               density_error_max=float(np.max(stats["ppe_density_error"])))
    last = read_frame(os.path.join(res["out"], "particles.h5"))
    res.update(flow_extent(last["x"][last["phase"] == PHASE_FLUID], up=2))
    return res


def write_record(rows, args, n) -> None:
    """The figures record ``bench_splishsplash`` (``jobs/figures.py``; written where
    ``$PARSPH_FIGURES`` says) from the rows of one rank count's runs: parsph at its default
    tolerance (``*_default``) and at the peer's (``*_peer_eta``), beside SPlisHSPlasH's."""
    from figures import record

    peer = next(r for r in rows if r["code"] == "splishsplash")
    fig = {"fluid": peer["fluid"], "n": n, "steps_peer": peer["steps"],
           "run_s_peer": peer["run_s"], "front_peer": peer["front"],
           "front_p999_peer": peer["front_p999"], "top_peer": peer["top"],
           "initial_density_max_peer": peer["initial_density_max"],
           "initial_density_floor_peer": peer["initial_density_floor"],
           "peak_rss_mib_peer": peer["peak_rss_mib_max"],
           "wall_offset": args.wall_offset}
    for row in rows:
        if row["code"] != "parsph" or row["cores"] != peer["cores"]:
            continue
        tag = ("default" if row["ppe_density_error"] == 0.0 else "peer_eta"
               if row["ppe_density_error"] == peer["ppe_density_error"] else None)
        if tag:
            fig.update({f"{k}_{tag}": row[k] for k in (
                "steps", "run_s", "front", "front_p999", "top", "ratio_vs_splishsplash",
                "core_time_ratio_vs_splishsplash", "front_vs_splishsplash",
                "front_p999_vs_splishsplash", "top_vs_splishsplash", "peak_rss_mib_max",
                "bytes_per_particle_peak_rss")})
    command = (f"python jobs/bench_splishsplash.py --fluid-particles {2 * n ** 3} --end-time "
               f"{args.end_time:g} --repeats {args.repeats} --density-error {args.density_error}"
               + (f" --wall-offset {args.wall_offset:g}" if args.wall_offset != WALL_OFFSET
                  else ""))
    record("bench_splishsplash", fig, ranks=peer["cores"], source="jobs/bench_splishsplash.py",
           command=command)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    size = ap.add_mutually_exclusive_group()
    size.add_argument("--fluid-particles", type=float, default=24000,
                      help="approximate fluid particle count (2 n^3; 24000: n = 23, 24,334)")
    size.add_argument("--spacing", type=float, default=None,
                      help="particle spacing d (m), rounded to a / n (SPlisHSPlasH's "
                           "particleRadius is d / 2)")
    ap.add_argument("--end-time", type=float, default=0.1, help="simulated time (s)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--ranks", default="1", help="parsph rank counts, e.g. 1,2")
    ap.add_argument("--threads", type=int, default=1, help="SPlisHSPlasH's OpenMP threads")
    ap.add_argument("--wall-offset", type=float, default=WALL_OFFSET, metavar="D",
                    help="SPlisHSPlasH's box this many particle sizes outside parsph's wall "
                         "planes (0.5: through parsph's first wall layer, where the peer's "
                         "fluid starts 6 %% over-dense; the docstring)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra parsph scene override (e.g. fluid.cfl=0.2)")
    ap.add_argument("--peer-set", action="append", default=[], metavar="KEY=VALUE",
                    help="SPlisHSPlasH Configuration override (e.g. IISPH.maxError=0.1)")
    ap.add_argument("--density-error", default="peer,0", metavar="ETA,...",
                    help="parsph's PPE tolerances, one run each: fluid.ppe_density_error "
                         "(relative RMS density error; 'peer': SPlisHSPlasH's IISPH.maxError "
                         "/ 100; 0: fluid.ppe_rtol alone, parsph's default)")
    ap.add_argument("--splishsplash-venv", default=os.path.join(
        tempfile.gettempdir(), "parsph-peers", "splishsplash"))
    ap.add_argument("--venv-python", default="python3",
                    help="the Python that makes the venv (the wheel is for 3.11)")
    ap.add_argument("--csv", default=None, help="append the figures to this CSV file "
                    "(long format of jobs/benchlib.py)")
    args = ap.parse_args()
    n = column_divisions(args.fluid_particles, args.spacing)
    d = A / n
    ranks = [int(r) for r in args.ranks.split(",")]
    py, mesh = ensure_splishsplash(args.splishsplash_venv, args.venv_python)
    work = tempfile.mkdtemp(prefix="splishsplash-bench-")
    with open(os.path.join(work, "dam_break_3d_splishsplash.py"), "w") as fh:
        fh.write(SPLISHSPLASH_SCRIPT)
    shutil.copy(mesh, os.path.join(work, "UnitBox.obj"))
    if not 0.0 <= args.wall_offset <= 2.0:
        sys.exit(f"--wall-offset {args.wall_offset:g}: give the peer's box offset in particle "
                 f"sizes, between 0 and 2 (0.6 starts its fluid at rest density)")
    peer_scene = splishsplash_scene(n, "UnitBox.obj", args.peer_set, args.wall_offset)
    iisph = peer_scene["Configuration"]["IISPH"]
    etas, peer_eta = density_errors(args.density_error, iisph), density_errors("peer", iisph)[0]
    scene = os.path.join(work, "dam_break_3d.toml")
    with open(scene, "w") as fh:
        fh.write(parsph_scene(n, args.end_time))
    load = os.getloadavg()[0]
    # warm-up: numba loads (or compiles) its cache
    run_parsph(ranks[0], scene, os.path.join(work, "warm-up"), [*args.set, "run.max_steps=4"])
    samples = {}
    for rep in range(args.repeats):
        for code, c, eta in [("splishsplash", args.threads, math.nan)] + [
                ("parsph", r, e) for r in ranks for e in etas]:
            res = (run_splishsplash(py, work, rep, peer_scene, args.end_time, args.threads, n,
                                    args.wall_offset)
                   if code == "splishsplash" else
                   run_parsph(c, scene, os.path.join(work, f"parsph_{c}_{eta:g}_{rep}"),
                              [*args.set, f"fluid.ppe_density_error={eta!r}"]))
            samples.setdefault((code, c, eta), []).append(res)
            print(f"# {code} cores={c}{'' if math.isnan(eta) else f' eta={eta:g}'} run "
                  f"{rep + 1}: {res['run_s']:.4g} s, {res['steps']} steps to t = "
                  f"{res['t_end']:.4g} s", file=sys.stderr, flush=True)
    rows = []
    for (code, c, eta), runs in samples.items():
        first = read_parsph(runs[0]) if code == "parsph" else runs[0]
        run_s = statistics.median(x["run_s"] for x in runs)
        rows.append({"code": code, "cores": c,  # SPlisHSPlasH: its mean's tolerance
                     "ppe_density_error": eta if code == "parsph" else peer_eta,
                     "fluid": first["fluid"],
                     "particles": first["particles"], "steps": first["steps"],
                     "t_end": first["t_end"], "run_s": run_s,
                     "process_s": statistics.median(x["process_s"] for x in runs),
                     "own_timer_s": statistics.median(x.get("own_timer_s", x["run_s"])
                                                      for x in runs),
                     "fluid_particle_steps_per_s_per_core":
                         first["fluid"] * first["steps"] / run_s / c,
                     "pressure_iterations": first["pressure_iterations"],
                     "pressure_iterations_max": first["pressure_iterations_max"],
                     "density_error_max": first.get("density_error_max", math.nan),
                     **{k: first[k] for k in ("front", "front_p999", "top")},
                     # the whole process of each rank (thread team) at its peak
                     "peak_rss_mib_max": max(first["peak_rss_mib"]),
                     "bytes_per_particle_peak_rss":
                         bytes_per_particle(first["peak_rss_mib"], first["particles"]),
                     **{k: first.get(k, math.nan)  # the peer's: its boundary's placement
                        for k in ("initial_density_max", "initial_density_floor")}})
    ref = next(x for x in rows if x["code"] == "splishsplash")
    info = samples[("splishsplash", args.threads, math.nan)][0]["info"]
    for row in rows:
        row["ratio_vs_splishsplash"] = cost_ratio(row["fluid_particle_steps_per_s_per_core"],
                                                  ref["fluid_particle_steps_per_s_per_core"])
        row["core_time_ratio_vs_splishsplash"] = (row["run_s"] * row["cores"]
                                                  / (ref["run_s"] * ref["cores"]))
        for key in ("front", "front_p999", "top"):  # the same flow?
            row[f"{key}_vs_splishsplash"] = row[key] / ref[key] - 1.0
        if row["fluid"] != ref["fluid"]:
            print(f"# warning: {row['code']} has {row['fluid']} fluid particles, SPlisHSPlasH "
                  f"{ref['fluid']}", file=sys.stderr, flush=True)
        metrics = {k: v for k, v in row.items() if k not in ("code", "cores", "particles")}
        record(args.csv, BENCHMARK, row["code"], 3, row["particles"], row["cores"], metrics)
    if ref["cores"] in ranks:
        write_record(rows, args, n)
    max_error = info["max_error"] if info["max_error"] is not None else float("nan")
    print(f"# column {n} x {n} x {2 * n} at d = a/{n} = {d:.6g} m (SPlisHSPlasH particleRadius "
          f"{info['radius']:.6g} m, IISPH maxError {max_error:.3g} %, cflFactor "
          f"{info['cfl']:.3g}, Akinci boundary {args.wall_offset:g} d outside parsph's walls: "
          f"{info['boundary_particles']} particles, its fluid at its first step "
          f"{info['initial_density_max']:.4f} rho0 at most, {info['initial_density_floor']:.4f} "
          f"on the floor; parsph walls: {WALL_LAYERS} layers), end time {args.end_time} s; "
          f"medians of {args.repeats} alternating run(s); load average {load:.2f} at start")
    print("# pressure_iterations: parsph median GMRES iterations of the PPE, SPlisHSPlasH "
          "mean Jacobi sweeps; ratio_vs_splishsplash: cost of a fluid particle-step per core; "
          "ppe_density_error: parsph's tolerance (0: ppe_rtol alone), density_error_max: the "
          "largest RMS density error its solves left (nan: not measured at ppe_rtol alone)")
    writer = csv.DictWriter(sys.stdout, list(rows[0]))
    writer.writeheader()
    writer.writerows([{k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()}
                      for r in rows])
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
