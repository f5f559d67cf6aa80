"""Earthquake loading: a ground-acceleration record added to gravity (paper section 6.3).

Record files are CSV: a header naming the columns with their units, then one row per
sample: time, then one acceleration column per axis of the scene (2 in 2D: x, y; 3 in
3D: x, y, z)::

    time (s), a_x (gal), a_y (gal), a_z (gal)
    0.00, 0.0, 0.0, 0.0
    0.01, 1.2, -0.4, 0.3

Units in parentheses or brackets: time ``s``; acceleration ``m/s2`` (or ``m/s^2``),
``gal`` (cm/s²) or ``g`` (9.80665 m/s²). Lines starting with ``#`` are comments.

The walls are fixed, so the simulation runs in the frame that moves with the ground: the
record enters the predictor of both phases as the body acceleration
``g − s a_ground(t − t_0)`` (``s`` = ``loading.scale``, ``t_0`` = ``loading.start_time``),
interpolated linearly; before the record and after its end it is zero. The acceleration
at a time is a pure function of the time, so a checkpoint needs no record position.
"""
from __future__ import annotations

import csv
import re
from dataclasses import dataclass

import numpy as np

from parsph.errors import SceneError

G0 = 9.80665
ACCEL_UNITS = {"m/s2": 1.0, "m/s^2": 1.0, "m/s**2": 1.0, "gal": 0.01, "cm/s2": 0.01,
               "cm/s^2": 0.01, "g": G0}
_UNIT = re.compile(r"[\(\[]\s*([^\)\]]+?)\s*[\)\]]")


@dataclass(frozen=True)
class Record:
    """A validated record: times (s) and ground accelerations (m/s²), one column per axis."""

    t: np.ndarray
    a: np.ndarray
    path: str

    def at(self, time: float) -> np.ndarray:
        """Ground acceleration at ``time`` (s); zero outside the record."""
        if time < self.t[0] or time > self.t[-1]:
            return np.zeros(self.a.shape[1])
        return np.array([np.interp(time, self.t, self.a[:, k]) for k in range(self.a.shape[1])])


def _unit(header: str, what: str, where: str) -> str:
    m = _UNIT.search(header)
    if not m:
        raise SceneError(f"{where}: column '{header.strip()}' gives no unit; write it as "
                         f"'{header.strip()} ({'s' if what == 'time' else 'gal'})'")
    return m.group(1).strip().lower()


def read_record(path: str, dim: int, key: str = "loading.record", source: str = "") -> Record:
    """Read and check an acceleration record; every problem names the file, line and fix."""
    where = f"{source}: key '{key}': record '{path}'" if source else f"record '{path}'"
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or "not a text file"
        raise SceneError(f"{where}: cannot read it ({reason})") from None
    if len(rows) < 3:
        raise SceneError(f"{where}: needs a header and at least two samples")
    header = rows[0]
    if len(header) != dim + 1:
        raise SceneError(f"{where}: has {len(header) - 1} acceleration columns; a {dim}D scene "
                         f"needs {dim} (time, then a_x, a_y{', a_z' if dim == 3 else ''})")
    if _unit(header[0], "time", where) != "s":
        raise SceneError(f"{where}: time must be in seconds, header says '{header[0].strip()}'")
    scale = []
    for col in header[1:]:
        unit = _unit(col, "acceleration", where)
        if unit not in ACCEL_UNITS:
            raise SceneError(f"{where}: unknown acceleration unit '{unit}' in '{col.strip()}'; "
                             f"use m/s2, gal or g")
        scale.append(ACCEL_UNITS[unit])
    data = np.empty((len(rows) - 1, dim + 1))
    for n, row in enumerate(rows[1:]):
        if len(row) != dim + 1:
            raise SceneError(f"{where}: data row {n + 1} has {len(row)} values, the header "
                             f"{dim + 1}")
        try:
            data[n] = [float(v) for v in row]
        except ValueError:
            raise SceneError(f"{where}: data row {n + 1} has a value that is not a number") \
                from None
    if not np.all(np.isfinite(data)):
        n = int(np.argmax(~np.isfinite(data).all(axis=1)))
        raise SceneError(f"{where}: data row {n + 1} has NaN or infinite values")
    t = data[:, 0]
    if np.any(np.diff(t) <= 0):
        n = int(np.argmax(np.diff(t) <= 0))
        raise SceneError(f"{where}: time is not increasing at data row {n + 2} "
                         f"({t[n]} then {t[n + 1]})")
    return Record(t=t, a=data[:, 1:] * np.array(scale), path=path)
