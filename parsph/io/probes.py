"""``probes.csv`` and ``probes_points.csv``: the samples of ``[[probes]]`` (rank 0).

``probes.csv`` is one tidy table, one row per value, flushed after every sample::

    time,probe,point,field,value
    0.1,gauge,0,p,4903.2...

``time`` is the simulated time of the step that took the sample (s), ``probe`` the
probe's name, ``point`` the station index (0 for a point or a box), ``field`` a field
name (vectors per component: ``v_x``; the stress per component: ``sigma_xy``), ``value``
the number (``nan`` where an average had no particle). Numbers are written as in
``stats.csv`` (:func:`parsph.io.stats.format_value`: they read back exactly).

``probes_points.csv`` gives the stations, one row per station::

    probe,type,measure,point,s,x,y[,z]

with ``s`` the distance from a line's start (m, 0 for points and boxes) and ``x, y, z``
its position (a box's centre). See ``docs/probes.md``.
"""
from __future__ import annotations

import csv
import os

import numpy as np

from parsph.errors import ParsphError
from parsph.io.stats import format_value

PROBES_FILE = "probes.csv"
POINTS_FILE = "probes_points.csv"
COLUMNS = ("time", "probe", "point", "field", "value")


def points_rows(items, dim) -> list[list[str]]:
    """Header and rows of ``probes_points.csv`` for sampler items (see the module doc)."""
    header = ["probe", "type", "measure", "point", "s"] + list("xyz"[:dim])
    rows = [header]
    for it in items:
        st = it.stations
        s = np.linalg.norm(st - st[0], axis=1)
        measure = "integral" if it.kind == "box" else it.kind
        for k in range(len(st)):
            rows.append([it.name, it.probe.type, measure, str(k), format_value(float(s[k]))]
                        + [format_value(float(c)) for c in st[k]])
    return rows


class ProbeWriter:
    """Writer of ``DIR/probes.csv`` and ``DIR/probes_points.csv`` (rank 0 only).

    Parameters
    ----------
    out : str
        Run directory.
    items : list
        The sampler's probes (``name``, ``probe``, ``kind``, ``stations``, ``columns``).
    dim : int
        2 or 3.
    resume_time : float or None
        None: a new run (both files written afresh). A time (s): a restart at that
        time; rows of ``probes.csv`` after it (written by a run that went on after its
        last checkpoint) are dropped and the samples are appended, so the file holds
        every sample once.

    Raises
    ------
    ParsphError
        If a file cannot be written, or an existing ``probes.csv`` has other columns.
    """

    def __init__(self, out, items, dim, resume_time=None):
        self.path = os.path.join(out, PROBES_FILE)
        self._fh = None
        points = os.path.join(out, POINTS_FILE)
        try:
            if resume_time is not None and os.path.isfile(self.path):
                _truncate(self.path, resume_time)
                mode = "a"
            else:
                mode = "w"
            with open(points, "w", newline="", encoding="utf-8") as fh:
                csv.writer(fh, lineterminator="\n").writerows(points_rows(items, dim))
            self._fh = open(self.path, mode, newline="", encoding="utf-8")
        except OSError as exc:
            raise ParsphError(f"cannot write {self.path} or {points} ({exc.strerror}); check "
                              f"the output directory and its permissions") from None
        self._csv = csv.writer(self._fh, lineterminator="\n")
        if mode == "w":
            self._csv.writerow(COLUMNS)
            self._fh.flush()

    def write(self, time: float, name: str, columns, values) -> None:
        """Append one sample of one probe (``values``: (n_points, len(columns))) and flush."""
        t = format_value(float(time))
        for k, row in enumerate(np.asarray(values)):
            for field, value in zip(columns, row):
                self._csv.writerow((t, name, k, field, format_value(float(value))))
        self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def _truncate(path: str, time: float) -> None:
    """Keep the header and the rows up to ``time`` (atomically: temporary file, rename)."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise ParsphError(f"cannot append to {path}: its header {rows[0] if rows else []} is "
                          f"not {','.join(COLUMNS)}; restart into a new output directory or "
                          f"move the old file")
    keep = [rows[0]] + [r for r in rows[1:] if r and float(r[0]) <= time]
    tmp = path + ".tmp"
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh, lineterminator="\n").writerows(keep)
    os.replace(tmp, path)


def remove_stale(out: str) -> None:
    """A new run without probes: drop the probe files an earlier run left in ``out``."""
    for name in (PROBES_FILE, POINTS_FILE):
        path = os.path.join(out, name)
        if os.path.isfile(path):
            os.remove(path)


def read_probes(path) -> dict[str, np.ndarray]:
    """Read ``probes.csv`` back: ``time`` (float), ``probe`` (str), ``point`` (int),
    ``field`` (str), ``value`` (float) arrays, one entry per row.

    Raises
    ------
    ParsphError
        If the file is missing or is not a probes table.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ParsphError(f"{path}: no such file; a run writes probes.csv when its scene has "
                          f"[[probes]]")
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise ParsphError(f"{path} is not a probes table (header {rows[0] if rows else []}, "
                          f"expected {','.join(COLUMNS)})")
    body = rows[1:]
    return {"time": np.array([float(r[0]) for r in body]),
            "probe": np.array([r[1] for r in body], dtype=str),
            "point": np.array([int(r[2]) for r in body], dtype=np.int64),
            "field": np.array([r[3] for r in body], dtype=str),
            "value": np.array([float(r[4]) for r in body])}
