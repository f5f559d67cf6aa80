"""``parsph study``: what accuracy costs in time.

Runs one scene at every combination of the varied settings (same rank count for all),
measures each run's error against the scene's reference (:mod:`parsph.verify.registry`) and
its wall time, and writes ``DIR/study.csv`` and ``DIR/study.png`` (error against wall time
on log axes, the Pareto front marked). Prints the observed order of convergence in the
particle size.

Varied settings are given as ``name=v1,v2,...``; the names ``particle_size``, ``cfl`` and
``ksp_rtol`` are short for the scene keys in :data:`ALIASES`, any other name is taken as
a dotted scene key. Without any, the study runs the scene's default sweep, the particle
sizes of its ``[study] particle_sizes`` (every built-in scene declares three).

A scene without a known answer (a landslide: ``slope_failure``) is judged by its
registered quantities (run-out, fluidised volume, time to rest;
:func:`parsph.verify.registry.quantities`): each is extrapolated to d = 0 from the three
finest sizes (Richardson, :func:`parsph.verify.registry.richardson`), written to
``DIR/richardson.csv`` with its observed order and error estimate, and each run's error
is its headline quantity's distance from the extrapolated value.
"""
from __future__ import annotations

import csv
import itertools
import logging
import math
import os

import numpy as np

from decomposition.reduce import broadcast
from parsph.errors import ParsphError

log = logging.getLogger("parsph")

#: Short names of the study axes -> the scene key they set, by what the scene runs:
#: (stage or mode, key); the first entry whose stage/mode the scene has wins.
ALIASES = {
    "particle_size": (("*", "domain.particle_size"),),
    "cfl": (("kinematic", "run.cfl"), ("iisph", "fluid.cfl"), ("tlsph", "solid.cfl")),
    "ksp_rtol": (("iisph", "fluid.ppe_rtol"),),
}
COLUMNS = ["particle_size", "cfl", "ksp_rtol", "ranks", "steps", "wall_s", "error"]


def parse_vary(items) -> dict:
    """``["particle_size=0.02,0.01", ...]`` -> ``{"particle_size": [0.02, 0.01], ...}``."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise ParsphError(f"--vary {item!r}: expected name=v1,v2,... e.g. "
                              f"--vary particle_size=0.02,0.01")
        name, values = item.split("=", 1)
        try:
            vals = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise ParsphError(f"--vary {item!r}: values must be numbers") from None
        if not vals or any(not math.isfinite(v) or v <= 0 for v in vals):
            raise ParsphError(f"--vary {item!r}: give one or more positive numbers")
        out[name.strip()] = vals
    return out


def _key_for(scene, name: str) -> str:
    """The dotted scene key a study axis sets for this scene."""
    from parsph.step.pipeline import plan

    runs = {s.name for s in plan(scene)} | {scene.run.mode, "*"}
    for what, key in ALIASES.get(name, (("*", name),)):
        section, _, attr = key.partition(".")
        if what in runs and hasattr(getattr(scene, section, None), attr):
            return key
    raise ParsphError(f"--vary {name}: scene '{scene.name}' has no setting '{name}' "
                      f"(it runs {', '.join(sorted(runs - {'*'}))})")


def _current(scene, key: str) -> float:
    section, _, attr = key.partition(".")
    return float(getattr(getattr(scene, section), attr))


def pareto(wall: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Mask of the runs no other run beats in both wall time and error."""
    keep = np.ones(len(wall), dtype=bool)
    for i in range(len(wall)):
        better = (wall <= wall[i]) & (error <= error[i]) & ((wall < wall[i]) | (error < error[i]))
        keep[i] = not better.any()
    return keep


def convergence_order(sizes, errors) -> float:
    """Least-squares slope of log(error) against log(particle size) (NaN if undefined)."""
    d, e = np.asarray(sizes, float), np.asarray(errors, float)
    ok = (e > 0) & np.isfinite(e)
    if len(np.unique(d[ok])) < 2:
        return float("nan")
    return float(np.polyfit(np.log(d[ok]), np.log(e[ok]), 1)[0])


def default_sweep(scene) -> dict:
    """The sweep of ``parsph study SCENE`` without ``--vary``: the scene's declared
    ``study.particle_sizes``; a clear error if it declares none."""
    sizes = list(scene.study.particle_sizes)
    if not sizes:
        raise ParsphError(
            f"scene '{scene.name}' ({scene.source}) declares no default sweep; give "
            "--vary NAME=V1,V2,... (e.g. --vary particle_size=0.04,0.02,0.01), or declare "
            "the sweep in the scene: [study] particle_sizes = [0.04, 0.02, 0.01] "
            "(coarse to fine, m; docs/scenes.md)")
    return {"particle_size": sizes}


def study(comm, scene_name: str, out: str, vary: dict | None = None, overrides=(),
          petsc_args=()) -> list:
    """Collective: run the sweep, write study.csv and study.png; return the rows.

    Parameters
    ----------
    comm : mpi4py communicator
        Every run uses all its ranks.
    scene_name : str
        Built-in scene name or TOML file; it needs a reference (:mod:`parsph.verify.registry`).
    out : str
        Directory for ``study.csv``, ``study.png`` and ``runs/NNN``.
    vary : dict, optional
        ``{name: [values]}`` (:func:`parse_vary`); empty or None: the scene's default
        sweep (:func:`default_sweep`).
    overrides : sequence of str
        ``KEY=VALUE`` settings applied to every run.
    petsc_args : sequence of str
        PETSc options of every run.

    Raises
    ------
    ParsphError
        On every rank, before any run, if the scene has no reference, no default sweep
        (when ``vary`` is empty) or no setting of a varied name.
    """
    from decomposition.comm import on_root
    from parsph.verify.registry import error_of, quantities_of, reference_of
    from parsph.step.run import run
    from parsph.scene.loader import load_scene

    base = on_root(comm, load_scene, scene_name, list(overrides))
    measure = quantities_of(base)
    if measure is None:
        reference_of(base)  # before any run: a scene without a known answer is refused
    if not vary:
        vary = default_sweep(base)
        log.info("study of '%s': its default sweep, particle_size = %s m (--vary overrides)",
                 base.name, ", ".join(f"{d:g}" for d in vary["particle_size"]))
    keys = {name: _key_for(base, name) for name in vary}
    names = list(vary)
    rows = []
    for i, combo in enumerate(itertools.product(*(vary[n] for n in names))):
        sets = [f"{keys[n]}={v!r}" for n, v in zip(names, combo)]
        scene = on_root(comm, load_scene, scene_name, list(overrides) + sets)
        run_dir = os.path.join(out, "runs", f"{i:03d}")
        summary = run(scene, run_dir, comm=comm, petsc_args=petsc_args, progress=False)
        row = {"particle_size": scene.domain.particle_size, "ranks": comm.size,
               "steps": summary["steps"], "wall_s": summary["wall_s"]}
        if measure is None:
            row["error"] = on_root(comm, error_of, scene, run_dir)
        else:
            row["error"] = float("nan")
            row.update({f"q_{k}": v for k, v in on_root(comm, measure, scene, run_dir).items()})
        for name in ("cfl", "ksp_rtol"):
            try:
                row[name] = _current(scene, _key_for(scene, name))
            except ParsphError:
                row[name] = float("nan")
        for name in extra_columns(names):  # any other varied key: a column of its own
            row[name] = _current(scene, keys[name])
        rows.append(row)
    extrapolated = extrapolate(rows, names) if measure is not None else []
    if comm.rank == 0:
        _write(out, rows, extrapolated)
    return broadcast(comm, rows)


def quantity_columns(rows: list) -> list[str]:
    """The measured quantities' columns (``q_NAME``), headline first."""
    return [k for k in (rows[0] if rows else {}) if k.startswith("q_")]


def extrapolate(rows: list, names) -> list[dict]:
    """Per quantity, :func:`parsph.verify.registry.richardson` over the particle sizes
    (only when the particle size alone is varied); sets each row's ``error``, the
    headline quantity's relative distance from its extrapolated value (or from the
    finest run's when no order could be read)."""
    from parsph.verify.registry import richardson

    if list(names) != ["particle_size"]:
        return []
    sizes = [r["particle_size"] for r in rows]
    out = []
    for key in quantity_columns(rows):
        fit = richardson(sizes, [r[key] for r in rows])
        fit["quantity"] = key[2:]
        out.append(fit)
    if out:
        head = out[0]
        ref = head["extrapolated"] if math.isfinite(head["extrapolated"]) else head["finest"]
        for r in rows:
            r["error"] = abs(r[quantity_columns(rows)[0]] - ref) / abs(ref) if ref else \
                float("nan")
    return out


RICHARDSON_COLUMNS = ("quantity", "finest", "previous_change", "last_change", "order",
                      "extrapolated", "error_estimate")


def extra_columns(names) -> list[str]:
    """The varied names that are not among :data:`COLUMNS` (dotted scene keys, e.g.
    ``fluid.ppe_density_error``): study.csv and the table get a column for each."""
    return [n for n in names if n not in COLUMNS and not n.startswith("q_")]


def table_columns(rows: list) -> list[str]:
    """The columns of study.csv: :data:`COLUMNS` with the varied dotted keys after
    ``ksp_rtol`` and the measured quantities at the end."""
    return COLUMNS[:3] + extra_columns(rows[0] if rows else []) + COLUMNS[3:] \
        + quantity_columns(rows)


def _write(out: str, rows: list, extrapolated=()) -> None:
    columns = table_columns(rows)
    with open(os.path.join(out, "study.csv"), "w", newline="") as fh:
        w = csv.DictWriter(fh, columns)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in columns})
    if extrapolated:
        with open(os.path.join(out, "richardson.csv"), "w", newline="") as fh:
            w = csv.DictWriter(fh, RICHARDSON_COLUMNS)
            w.writeheader()
            for fit in extrapolated:
                w.writerow({k: fit[k] for k in RICHARDSON_COLUMNS})
    plot(rows, os.path.join(out, "study.png"), extrapolated)


def point_labels(rows: list) -> list[str]:
    """A label per run of the settings that vary over the study (``d`` if none does)."""
    short = {"particle_size": "d", "cfl": "cfl", "ksp_rtol": "rtol"}
    short.update({k: k.rsplit(".", 1)[-1] for k in extra_columns(rows[0] if rows else [])})
    varied = [k for k in short if len({repr(r[k]) for r in rows}) > 1] or ["particle_size"]
    return [", ".join(f"{short[k]}={r[k]:.3g}" for k in varied) for r in rows]


def plot(rows: list, path: str, extrapolated=()) -> None:
    """``study.png``: error against wall time (log axes, the Pareto front marked); with
    extrapolated quantities, each one's relative distance from its value at d = 0
    against wall time, and the quantities against d beside."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    wall = np.array([r["wall_s"] for r in rows])
    fig = Figure(figsize=(11 if extrapolated else 6, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 2 if extrapolated else 1, 1)
    if extrapolated:
        for k, fit in enumerate(extrapolated):
            ref = fit["extrapolated"] if math.isfinite(fit["extrapolated"]) else fit["finest"]
            err = np.array([abs(r["q_" + fit["quantity"]] - ref) / abs(ref) if ref else
                            np.nan for r in rows])
            ok = err > 0
            ax.loglog(wall[ok], err[ok], "o-", color=f"C{k}", label=fit["quantity"])
        ax.set_ylabel("relative distance from the value at d = 0 (-)")
    else:
        err = np.array([r["error"] for r in rows])
        front = pareto(wall, err)
        ax.loglog(wall, err, "o", color="0.6", label="runs")
        order = np.argsort(wall[front])
        ax.loglog(wall[front][order], err[front][order], "o-", color="C3", label="Pareto front")
        for text, w, e in zip(point_labels(rows), wall, err):
            ax.annotate(text, (w, e), fontsize=7, textcoords="offset points", xytext=(3, 3))
        ax.set_ylabel("error (-)")
    ax.set_xlabel("wall time (s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if extrapolated:
        d = np.array([r["particle_size"] for r in rows])
        ax2 = fig.add_subplot(1, 2, 2)
        for k, fit in enumerate(extrapolated):
            q = np.array([r["q_" + fit["quantity"]] for r in rows])
            scale = abs(fit["finest"]) or 1.0
            ax2.plot(d, q / scale, "o-", color=f"C{k}", label=fit["quantity"])
            if math.isfinite(fit["extrapolated"]):
                ax2.errorbar([0.0], [fit["extrapolated"] / scale],
                             yerr=[fit["error_estimate"] / scale], fmt="s", color=f"C{k}",
                             capsize=3)
        ax2.set_xlabel("particle size d (m)")
        ax2.set_ylabel("quantity / its finest value (-); square: d = 0")
        ax2.set_xlim(left=-0.05 * d.max())
        ax2.grid(True, alpha=0.3)
        ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
