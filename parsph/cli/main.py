"""Command line: ``parsph run|check|scenes|info|plot|study|maps``.

Every verb works the same on 1 rank and under ``mpirun -n N``. Bad input ends with one
message on rank 0, no traceback, exit status 2, on every rank; a numerical failure with
exit status 3; a run stopped by SIGTERM/SIGUSR1 writes a checkpoint and exits with 4. A bug (any other exception) prints its traceback and aborts all ranks so
that none hangs.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
import traceback

from parsph import __version__
from parsph.errors import NumericalError, ParsphError, Preempted

EXIT_OK, EXIT_BUG, EXIT_INPUT, EXIT_NUMERICAL, EXIT_PREEMPTED = 0, 1, 2, 3, 4
VERBS = ("run", "check", "scenes", "info", "plot", "study", "maps")
DEFAULT_SCENE = "slope_failure"


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of printing on every rank and exiting."""

    def error(self, message):
        raise ParsphError(f"{self.prog}: {message} (see `{self.prog} --help`)")


def _parser() -> _Parser:
    p = _Parser(prog="parsph", description="Phase-change TLSPH-IISPH landslide simulation "
                "on MPI and PETSc. PETSc options (-ppe_ksp_monitor, -log_view, ...) pass through.")
    p.add_argument("--version", action="version", version=f"parsph {__version__}")
    sub = p.add_subparsers(dest="verb", metavar="{run,check,scenes,info,plot,study,maps}",
                           parser_class=_Parser)
    r = sub.add_parser("run", help="run a scene (default: the built-in default scene)")
    r.add_argument("scene", nargs="?", default=DEFAULT_SCENE,
                   help="built-in scene name or TOML file (default: %(default)s)")
    r.add_argument("--out", default=None, help="output directory (default: out/SCENE)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set domain.particle_size=0.01")
    r.add_argument("--restart", default=None, metavar="FILE",
                   help="start from DIR/checkpoint.h5: continue that run in DIR, or with "
                   "--out NEW branch it into a new run directory (DIR left untouched)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar")
    r.add_argument("-v", "--verbose", action="store_true", help="debug logging on rank 0")
    c = sub.add_parser("check", help="print stages, particle counts per rank, memory and each body as filled")
    c.add_argument("scene", help="built-in scene name or TOML file")
    c.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    sub.add_parser("scenes", help="list the built-in scenes")
    sub.add_parser("info", help="versions of MPI, mpi4py, PETSc/hypre, HDF5, numba, numpy")
    pl = sub.add_parser("plot", help="render frames (or the time series) of a run to PNG")
    pl.add_argument("dir", help="run output directory (with particles.h5, stats.csv)")
    pl.add_argument("--frames", default=None,
                    help="last | all | comma-separated steps, first, last (e.g. first,last); "
                    "default last, none with --series alone")
    pl.add_argument("--series", action="store_true",
                    help="stats.csv (and probes.csv) over time in one PNG, series.png")
    pl.add_argument("--color-by", default="phase,speed,eps_p",
                    help="comma-separated: phase, speed, eps_p, p, rho, rank")
    pl.add_argument("--out", default=None,
                    help="directory for the PNG files (default: DIR/plots)")
    st = sub.add_parser("study", help="error against wall time over a sweep of settings")
    st.add_argument("scene", help="built-in scene name or TOML file with a known answer")
    st.add_argument("--out", required=True, help="directory for study.csv, study.png, runs/")
    st.add_argument("--vary", nargs="+", default=[], metavar="NAME=V1,V2",
                    help="particle_size=..., cfl=..., ksp_rtol=... or any dotted scene key "
                    "(default: the scene's [study] particle_sizes)")
    st.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    mp = sub.add_parser("maps", help="rasters of a 3D run over the terrain: deposit, erosion, "
                        "flow depth, speed, arrival (GeoTIFF, PNG, summary.json)")
    mp.add_argument("dir", help="run output directory (with particles.h5)")
    mp.add_argument("--cell", type=_number, default=None, metavar="SIZE",
                    help="cell size in m (default: the height map's; required without one)")
    mp.add_argument("--scene", default=None, metavar="FILE",
                    help="the run's scene file, if it is no longer where the run read it")
    mp.add_argument("--out", default=None, help="directory for the maps (default: DIR/maps)")
    mp.add_argument("--speed-threshold", type=_number, default=None, metavar="V",
                    help="speed in m/s above which material is flowing (default 0.1)")
    mp.add_argument("--min-thickness", type=_number, default=None, metavar="H",
                    help="erosion or deposit in m from which a cell counts as source or "
                    "deposit (areas, crown, toe; default d/4)")
    mp.add_argument("--flowing", choices=("any", "fluid"), default="any",
                    help="what, faster than the threshold, is flowing: any material (default) "
                    "or only the fluid, the debris of the phase change (earthquake scenes)")
    mp.add_argument("--no-png", action="store_true", help="GeoTIFF and summary.json only")
    return p


def _number(text: str) -> float:
    """argparse type: a float (argparse names the option and the value otherwise)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def cmd_maps(comm, args) -> int:
    from parsph.maps.compute import make_maps

    summary = make_maps(comm, args.dir, cell=args.cell, scene=args.scene, out=args.out,
                        speed_threshold=args.speed_threshold, min_thickness=args.min_thickness,
                        flowing=args.flowing, pictures=not args.no_png)
    if comm.rank == 0:
        for path in summary["files"]:
            print(path)
    return EXIT_OK


def cmd_study(comm, args, petsc) -> int:
    from parsph.cli.study import (convergence_order, extra_columns, parse_vary, quantity_columns,
                                  study)

    rows = study(comm, args.scene, args.out, parse_vary(args.vary), args.overrides, petsc)
    if comm.rank == 0:
        extra = extra_columns(rows[0] if rows else [])
        print(f"{'particle_size':>14s} {'cfl':>8s} {'ksp_rtol':>9s} "
              + "".join(f"{k:>{max(len(k), 9)}s} " for k in extra)
              + f"{'steps':>7s} {'wall_s':>9s} {'error':>10s}")
        for r in rows:
            print(f"{r['particle_size']:14.4g} {r['cfl']:8.3g} {r['ksp_rtol']:9.2g} "
                  + "".join(f"{r[k]:>{max(len(k), 9)}.3g} " for k in extra)
                  + f"{r['steps']:7d} {r['wall_s']:9.3f} {r['error']:10.3e}")
        quantities = quantity_columns(rows)
        if quantities:
            _print_quantities(rows, quantities, args.out)
        else:
            order = convergence_order([r["particle_size"] for r in rows],
                                      [r["error"] for r in rows])
            print(f"observed order of convergence in the particle size: {order:.2f}")
        print(f"wrote {os.path.join(args.out, 'study.csv')} and "
              f"{os.path.join(args.out, 'study.png')}")
    return EXIT_OK


def _print_quantities(rows, quantities, out) -> None:
    """The measured quantities per run and, from DIR/richardson.csv, their values
    extrapolated to d = 0."""
    import csv

    print("quantities: " + ", ".join(f"{k[2:]}" for k in quantities))
    for r in rows:
        print(f"  d = {r['particle_size']:.4g} m: "
              + ", ".join(f"{r[k]:.4g}" for k in quantities) + f" ({r['wall_s']:.1f} s)")
    path = os.path.join(out, "richardson.csv")
    if not os.path.exists(path):
        return
    with open(path) as fh:
        for fit in csv.DictReader(fh):
            vals = {k: float(v) for k, v in fit.items() if k != "quantity"}
            print(f"  {fit['quantity']}: finest {vals['finest']:.4g}, changes "
                  f"{vals['previous_change']:+.3g} then {vals['last_change']:+.3g}, order "
                  f"{vals['order']:.2f}, at d = 0: {vals['extrapolated']:.4g} "
                  f"+- {vals['error_estimate']:.2g}")


def _is_petsc_option(tok: str) -> bool:
    """``-name`` with one dash and a name of two or more characters (parsph's own short
    flags are ``-h`` and ``-v``; its long options have two dashes)."""
    return tok.startswith("-") and not tok.startswith("--") and len(tok) > 2 \
        and not _is_number(tok)


def split_petsc_options(argv: list[str]) -> tuple[list[str], list[str]]:
    """``(parsph arguments, PETSc options)``: the PETSc options (``-name [value]``, the
    value being the next argument unless it starts with a dash and is no number, as
    PETSc reads them) are taken out before argparse sees the rest. argparse alone would
    read ``-visc_ksp_monitor`` as ``-v isc_ksp_monitor`` and the value of ``-ppe_ksp_rtol
    1e-10`` as the scene.

    Raises
    ------
    ParsphError
        If the value of a PETSc option is a scene (``parsph run -ppe_ksp_monitor
        dam_break``): the scene must come before PETSc options that may take a value.
    """
    from parsph.scene.loader import builtin_names

    scenes = builtin_names()
    ours, petsc = [], []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if not _is_petsc_option(tok):
            ours.append(tok)
            i += 1
            continue
        petsc.append(tok)
        value = argv[i + 1] if i + 1 < len(argv) else None
        if value is not None and (not value.startswith("-") or _is_number(value)):
            if value in scenes or value.endswith(".toml"):
                raise ParsphError(
                    f"'{value}' follows the PETSc option '{tok}' and would be its value; name "
                    f"the scene before PETSc options, e.g. `parsph run {value} {tok}`")
            petsc.append(value)
            i += 1
        i += 1
    return ours, petsc


def _is_number(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False


def _load(comm, scene_name, overrides):
    """Load and validate the scene on rank 0; every rank gets the scene or the same error."""
    from decomposition.comm import on_root
    from parsph.scene.loader import load_scene

    return on_root(comm, load_scene, scene_name, overrides)


def cmd_run(comm, args, petsc) -> int:
    from parsph.step.pipeline import needs_petsc, plan
    from parsph.step.run import run

    scene = _load(comm, args.scene, args.overrides)
    specs = plan(scene)
    if petsc and not needs_petsc(specs, scene) and comm.rank == 0:
        logging.getLogger("parsph").warning(
            "PETSc options %s ignored: scene '%s' solves no implicit system", " ".join(petsc),
            scene.name)
    if args.out:
        out = args.out
    elif args.restart:
        out = os.path.dirname(os.path.abspath(args.restart))
    else:
        out = f"out/{scene.name}"
    run(scene, out, comm=comm, petsc_args=petsc, progress=False if args.no_progress else None,
        restart=args.restart)
    return EXIT_OK


def cmd_check(comm, args) -> int:
    from parsph.cli.check import check

    text = check(comm, _load(comm, args.scene, args.overrides))
    if comm.rank == 0:
        print(text)
    return EXIT_OK


def cmd_scenes(comm) -> int:
    from parsph.scene.loader import builtin_names, load_scene

    if comm.rank == 0:
        for name in builtin_names():
            print(f"{name:22s} {load_scene(name).scene.description}")
    return EXIT_OK


def cmd_info(comm) -> int:
    from parsph.cli.info import info

    rows = info()
    if comm.rank == 0:
        width = max(len(k) for k in rows)
        for key, value in rows.items():
            print(f"{key:{width}s}  {value}")
    return EXIT_OK


def _frame_steps(run_dir, text):
    """``--frames``: "last", "all" or the sorted steps of a comma-separated list."""
    if text in ("last", "all"):
        return text
    from parsph.io import read_frames

    steps = None
    picked = []
    for token in text.split(","):
        token = token.strip()
        if token in ("first", "last"):
            steps = steps or [s for s, _ in read_frames(run_dir)]
            picked.append(steps[0] if token == "first" else steps[-1])
        elif token.isdigit():
            picked.append(int(token))
        else:
            raise ParsphError(f"--frames {text!r}: give last, all, or a comma-separated list "
                              f"of steps, first and last")
    return sorted(set(picked))


def cmd_plot(comm, args) -> int:
    from parsph.io.plot import plot_run

    if comm.rank == 0:
        frames = None
        if args.frames is not None or not args.series:
            frames = _frame_steps(args.dir, args.frames or "last")
        if args.series:
            from parsph.io.series import plot_series

            out = os.path.join(args.out or os.path.join(args.dir, "plots"), "series.png")
            print(plot_series(args.dir, out)[0])
        if frames is not None:
            color_by = tuple(s.strip() for s in args.color_by.split(",") if s.strip())
            for path in plot_run(args.dir, out=args.out, color_by=color_by, frames=frames):
                print(path)
    return EXIT_OK


def main(argv=None) -> int:
    """Entry point of the ``parsph`` console script and ``python -m parsph``."""
    from decomposition import world
    from decomposition.comm import abort
    from parsph.log import setup_logging

    comm = world()
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        ours, petsc = split_petsc_options(argv)
        args, extra = _parser().parse_known_args(ours)
        setup_logging(comm, verbose=getattr(args, "verbose", False))
        if args.verb is None:
            raise ParsphError(f"no command given; commands: {', '.join(VERBS)} "
                              f"(see `parsph --help`)")
        for tok in extra:
            if tok.startswith("--"):
                raise ParsphError(f"unknown option '{tok}' (see `parsph {args.verb} --help`; "
                                  f"PETSc options take a single dash, e.g. -ppe_ksp_monitor)")
        if extra:
            raise ParsphError(f"unexpected argument(s) {' '.join(extra)} for `parsph {args.verb}` "
                              f"(see `parsph {args.verb} --help`)")
        if petsc and args.verb not in ("run", "study"):
            raise ParsphError(f"unexpected argument(s) {' '.join(petsc)} for `parsph {args.verb}` "
                              f"(PETSc options go to `parsph run` and `parsph study`)")
        if args.verb == "run":
            return cmd_run(comm, args, petsc)
        if args.verb == "check":
            return cmd_check(comm, args)
        if args.verb == "scenes":
            return cmd_scenes(comm)
        if args.verb == "info":
            return cmd_info(comm)
        if args.verb == "study":
            return cmd_study(comm, args, petsc)
        if args.verb == "maps":
            return cmd_maps(comm, args)
        return cmd_plot(comm, args)
    except Preempted as exc:
        if comm.rank == 0:
            print(f"parsph: {exc}", file=sys.stderr)
        return EXIT_PREEMPTED
    except NumericalError as exc:
        if comm.rank == 0:
            print(f"parsph: numerical failure: {exc}", file=sys.stderr)
        return EXIT_NUMERICAL
    except ParsphError as exc:
        if comm.rank == 0:
            print(f"parsph: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except SystemExit:
        raise
    except BaseException:  # noqa: BLE001 - a bug: show it and take every rank down
        traceback.print_exc()
        sys.stderr.flush()
        abort(comm, EXIT_BUG)
        return EXIT_BUG
