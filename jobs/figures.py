"""Figures that cannot go stale: the runs that measure them record them, the pages quote them.

**Records.** A test or job calls :func:`record` with its measured figures. It prints them
on one line, ``figures NAME: key = value, ...`` (``jobs/verify.sh`` puts these lines in
its table), and, when ``PARSPH_FIGURES`` names a directory, writes them there as
``NAME.json``: ``{"name", "source", "command", "ranks", "date", "figures": {...}}``. A run
directory of ``parsph run`` is recorded by ``python jobs/figures.py run NAME DIR`` (the
figures of :func:`run_figures`); a benchmark's headline, which no test or CI job measures
(timings are never taken on a shared machine by a script), by ``python jobs/figures.py set
NAME KEY=VALUE ... --command CMD`` from the figures its job printed. The records the
pages quote live in ``docs/figures/``.

**Pages.** README.md and docs/*.md quote a recorded figure as

    <!--{NAME.KEY:FORMAT}-->VALUE<!--/-->

(``FORMAT`` a Python format spec, optional, or ``code`` for a code span; ``KEY[i]`` an
item of a list; ``KEY`` may also be a record's ``command`` or ``date``). The comments
do not show in the rendered page. ``python jobs/figures.py`` rewrites every ``VALUE`` from
the records; ``tests/test_figures.py`` fails when a page's value differs from its record.

Usage::

    python jobs/figures.py                     # rewrite the pages from docs/figures/
    python jobs/figures.py --check             # list the values that differ; exit 1 if any
    python jobs/figures.py --take DIR          # copy DIR's records into docs/figures/, rewrite
    python jobs/figures.py run NAME DIR [--direction=-1,0] [--command CMD]
                                               # record a run directory, rewrite
    python jobs/figures.py set NAME KEY=VALUE ... --command CMD [--ranks R]
                                               # record figures a job printed, rewrite

To refresh the figures of the slow tests: ``bash jobs/verify.sh`` then
``python jobs/figures.py --take out/verify/figures``; of the CI tests:
``PARSPH_FIGURES=out/figures bash scripts/test.sh`` then ``--take out/figures``.
"""
from __future__ import annotations

import argparse
import datetime
import glob
import json
import math
import os
import re
import shutil
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
#: where the records live in the repository
FIGURES = os.path.join(ROOT, "docs", "figures")
#: a quoted figure: <!--{NAME.KEY:FORMAT}-->VALUE<!--/--> (not right after a backtick: the
#: syntax shown in a code span is no quote)
MARK = re.compile(r"(?<!`)<!--\{(?P<field>[^}:]+)(?::(?P<spec>[^}]*))?\}-->(?P<value>.*?)"
                  r"<!--/-->", re.S)


def pages() -> list[str]:
    """The pages that may quote figures: README.md and docs/*.md (relative to the root)."""
    found = ["README.md"] + sorted(os.path.relpath(p, ROOT) for p in
                                   glob.glob(os.path.join(ROOT, "docs", "**", "*.md"),
                                             recursive=True))
    return [p for p in found if os.path.exists(os.path.join(ROOT, p))]


def _plain(value):
    """A JSON value: numpy scalars as Python numbers, floats to 6 significant digits."""
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else None
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def record(name: str, figures: dict, *, ranks: int = 1, command: str | None = None,
           source: str | None = None) -> dict:
    """Print ``figures`` (a flat dict of numbers, strings or lists) as one line and, if
    ``PARSPH_FIGURES`` is set, write them to ``$PARSPH_FIGURES/NAME.json``; call it on
    one rank only. A record is not replaced by one from fewer ``ranks`` (a test that runs
    in the one-rank and the two-rank session keeps its two-rank figures).

    ``source`` defaults to the running test (``PYTEST_CURRENT_TEST``), ``command`` to
    the command that reruns it on ``ranks`` ranks. Returns the record."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise ValueError(f"figure record name {name!r}: letters, digits, '_', '.', '-' only")
    test = os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0]
    source = source or test or "unknown"
    if command is None and test:
        py = ".venv/bin/python -m pytest" if ranks == 1 else \
            f"mpirun -n {ranks} .venv/bin/python -m mpi4py -m pytest"
        command = f"{py} -s --slow '{test}'"
    rec = {"name": name, "source": source, "command": command or "", "ranks": int(ranks),
           "date": datetime.date.today().isoformat(), "figures": _plain(dict(figures))}
    print(f"figures {name}: " + ", ".join(f"{k} = {v}" for k, v in rec["figures"].items()),
          flush=True)
    folder = os.environ.get("PARSPH_FIGURES")
    if folder:
        write(rec, folder)
    return rec


def write(rec: dict, folder: str = FIGURES) -> bool:
    """Write a record to ``folder/NAME.json`` unless the one there has more ranks; True
    if written."""
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"{rec['name']}.json")
    if os.path.exists(path):
        with open(path, encoding="utf-8") as fh:
            if json.load(fh).get("ranks", 1) > rec["ranks"]:
                return False
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(rec, fh, indent=1, sort_keys=True)
        fh.write("\n")
    return True


def load(folder: str = FIGURES) -> dict:
    """``{name: record}`` of every ``*.json`` in ``folder``; a malformed record is an error
    naming its file."""
    out = {}
    for path in sorted(glob.glob(os.path.join(folder, "*.json"))):
        with open(path, encoding="utf-8") as fh:
            rec = json.load(fh)
        name = os.path.basename(path)[:-5]
        missing = {"name", "source", "command", "ranks", "date", "figures"} - set(rec)
        if missing or rec["name"] != name or not isinstance(rec["figures"], dict):
            raise ValueError(f"{path}: not a figure record named {name!r} (missing "
                             f"{sorted(missing)} or another name); write it with record()")
        out[name] = rec
    return out


def value(records: dict, field: str):
    """The figure ``NAME.KEY`` or ``NAME.KEY[i]`` (a record name may hold dots, a key
    not), or the record's own ``command``, ``date`` or ``ranks``."""
    name, _, key = field.strip().rpartition(".")
    index = None
    if key.endswith("]") and "[" in key:
        key, index = key[:-1].split("[")
    if name not in records:
        raise KeyError(f"no figure record {name!r} in docs/figures/ (field {field!r})")
    figures = records[name]["figures"]
    if key not in figures and key in ("command", "date", "ranks"):
        return records[name][key]
    if key not in figures:
        raise KeyError(f"record {name!r} has no figure {key!r} (it has {sorted(figures)})")
    out = figures[key]
    return out[int(index)] if index is not None else out


def _show(v, spec: str) -> str:
    if v is None:
        return "n/a"
    if spec == "code":
        return f"`{v}`"
    return format(v, spec)


def render(text: str, records: dict) -> tuple[str, list]:
    """``text`` with every quoted figure's value rewritten from ``records``, and the list
    of ``(field, page value, recorded value)`` that differed."""
    differ = []

    def one(m):
        shown = _show(value(records, m["field"]), m["spec"] or "")
        if m["value"] != shown:
            differ.append((m["field"], m["value"], shown))
        return m[0][:m.start("value") - m.start()] + shown + "<!--/-->"

    return MARK.sub(one, text), differ


def rewrite(records: dict | None = None, check: bool = False) -> dict:
    """Rewrite (or with ``check``, only compare) every page; ``{page: differences}``."""
    records = load() if records is None else records
    out, new = {}, {}
    for page in pages():  # every page first: a missing record leaves all of them alone
        with open(os.path.join(ROOT, page), encoding="utf-8") as fh:
            new[page], differ = render(fh.read(), records)
        if differ:
            out[page] = differ
    for page in out if not check else ():
        with open(os.path.join(ROOT, page), "w", encoding="utf-8") as fh:
            fh.write(new[page])
    return out


def run_figures(out: str, direction=None) -> dict:
    """The figures of a ``parsph run`` directory: from ``stats.csv`` the steps, end
    time, wall seconds, fluidised count and volume and the time of the first, the farthest
    particle (``front``), the kinetic-energy peak and when it first falls below 1 % of it
    after the peak, from when every particle stays below 5 cm/s (``at_rest_from_s``), the
    top speed (and the last step's, ``max_speed_end_m_s``) and the energy balance's largest rise relative to the peak kinetic energy,
    in a step and over a stretch (``energy_rise_max``, ``energy_gain_max``); from the first and the last frame the
    particles by phase (``*_start`` at the first) and, along ``direction`` (default: none), the run-out: the coordinate along it that
    99 % of the non-wall particles stay behind (``front`` is their largest)."""
    import numpy as np

    from parsph.io import read_frame, read_stats

    s = read_stats(os.path.join(out, "stats.csv"))
    t, ke = s["time"], s["kinetic_energy"]
    peak = int(np.argmax(ke))
    below = np.nonzero(ke[peak:] < 1e-2 * ke[peak])[0]
    fig = {"steps": len(t), "end_time_s": t[-1], "wall_s": s["elapsed_s"][-1],
           "ke_peak_j": ke[peak], "ke_peak_time_s": t[peak],
           "below_1pc_of_peak_from_s": t[peak + below[0]] if len(below) else float("nan"),
           "max_speed_m_s": s["max_speed"].max(), "max_speed_end_m_s": s["max_speed"][-1]}
    for key, column in (("n_fluidised", "n_fluidised"), ("fluidised", "fluidised_volume"),
                        ("front_m", "front"), ("energy_rise_max", "energy_rise_max"),
                        ("energy_gain_max", "energy_gain_max")):
        if column in s:
            fig[key] = s[column][-1]
    if "n_fluidised" in fig:
        fig["n_fluidised"] = int(fig["n_fluidised"])
        some = np.nonzero(s["n_fluidised"] > 0)[0]
        fig["first_fluidised_s"] = t[some[0]] if len(some) else float("nan")
    moving = np.nonzero(s["max_speed"] >= 0.05)[0]  # at rest: below 5 cm/s from then on
    fig["at_rest_from_s"] = (t[moving[-1] + 1] if moving[-1] + 1 < len(t) else float("nan")) \
        if len(moving) else t[0]
    first = read_frame(os.path.join(out, "particles.h5"), 0)
    last = read_frame(os.path.join(out, "particles.h5"), "last")
    fig["particles"] = len(first["phase"])
    for phase, key in ((0, "solid_particles"), (1, "fluid_particles"), (2, "wall_particles")):
        fig[key] = int(np.count_nonzero(last["phase"] == phase))
        fig[f"{key}_start"] = int(np.count_nonzero(first["phase"] == phase))
    if direction is not None:
        from parsph.verify.coupling import run_out_along

        fig["runout_99_m"] = run_out_along(last, direction)
    return fig


def _run_source(path: str) -> str:
    """``source`` of a run directory's record: its path inside the repository, else only
    its name (a path outside says nothing to another reader; ``command`` remakes it)."""
    full = os.path.abspath(path)
    if os.path.commonpath([full, ROOT]) == ROOT:
        return f"parsph run directory {os.path.relpath(full, ROOT)}"
    return f"parsph run directory .../{os.path.basename(full.rstrip(os.sep))}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python jobs/figures.py",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="only list the values that differ")
    ap.add_argument("--take", metavar="DIR", help="copy DIR's records into docs/figures/ first")
    sub = ap.add_subparsers(dest="verb")
    r = sub.add_parser("run", help="record a parsph run directory's figures, then rewrite")
    r.add_argument("name")
    r.add_argument("dir")
    r.add_argument("--direction", help="run-out direction, e.g. -1,0 (default: no run-out)")
    r.add_argument("--command", default="", help="the command that made the run")
    r.add_argument("--ranks", type=int, default=2)
    s = sub.add_parser("set", help="record figures a job printed (KEY=VALUE, numbers or "
                       "text), then rewrite")
    s.add_argument("name")
    s.add_argument("pairs", nargs="+", metavar="KEY=VALUE")
    s.add_argument("--command", required=True, help="the job's command line")
    s.add_argument("--ranks", type=int, default=1)
    s.add_argument("--date", help="the day the job ran (default today), YYYY-MM-DD")
    args = ap.parse_args(argv)
    if args.take:
        for name, rec in load(args.take).items():
            shutil.copyfile(os.path.join(args.take, f"{name}.json"),
                            os.path.join(FIGURES, f"{name}.json"))
            print(f"took {name} ({rec['source']}, {rec['date']})")
    if args.verb == "run":
        sys.path.insert(0, ROOT)
        direction = [float(v) for v in args.direction.split(",")] if args.direction else None
        rec = record(args.name, run_figures(args.dir, direction), ranks=args.ranks,
                     command=args.command, source=_run_source(args.dir))
        write(rec, os.environ.get("PARSPH_FIGURES", FIGURES))
    if args.verb == "set":
        pairs = {}
        for pair in args.pairs:
            key, eq, text = pair.partition("=")
            if not eq:
                ap.error(f"{pair!r}: expected KEY=VALUE")
            try:
                pairs[key] = json.loads(text)
            except json.JSONDecodeError:
                pairs[key] = text
        rec = record(args.name, pairs, ranks=args.ranks, command=args.command,
                     source="set by hand from the job's printed figures")
        if args.date:
            rec["date"] = datetime.date.fromisoformat(args.date).isoformat()
        write(rec)
    try:
        differ = rewrite(check=args.check)
    except KeyError as exc:  # a quoted figure without its record: name it, change nothing
        print(f"python jobs/figures.py: {exc.args[0]}; no page rewritten", file=sys.stderr)
        return 1
    for page, items in differ.items():
        for field, old, new in items:
            print(f"{page}: {field}: {old!r} -> {new!r}")
    if args.check:
        return 1 if differ else 0
    print(f"rewrote {len(differ)} page(s)" if differ else "pages agree with docs/figures/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
