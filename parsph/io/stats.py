"""``stats.csv``: one row per step, written by rank 0.

Rows reach the file at least once a second of wall time (``flush_seconds``), at every
:meth:`StatsWriter.flush` (the run calls it before each checkpoint and at its end) and
when the writer closes, also on an error: a run killed outright loses at most the last
second's rows, never those of a checkpoint it could restart from. (Formatted and flushed
row by row they had cost 45-70 us of a 2D coupled step's 1 ms of fixed cost,
jobs/bench_overhead.py.)

Columns are fixed when the writer is created (time in s, dt in s, KSP iterations and
residuals, particle counts per phase, kinetic energy in J, wall seconds per stage, ...;
the run decides which). Numbers are written so that they read back exactly: floats with
:func:`repr` (shortest round-trip form, e.g. ``0.1``, ``1e-05``, ``nan``), integers in
full, booleans as 1/0. A missing key leaves its cell empty.
"""
from __future__ import annotations

import csv
import math
import numbers
import os
import time

import numpy as np

from parsph.errors import ParsphError


def format_value(value) -> str:
    """The CSV text of one cell (empty for None)."""
    kind = type(value)
    if kind is float:  # the common cells first (a row a step): no ABC checks
        return repr(value)  # nan too
    if kind is int:
        return str(value)
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        value = float(value)
        if math.isnan(value):
            return "nan"
        return repr(value)
    if isinstance(value, str):
        return value
    raise TypeError(f"stats value {value!r} of type {type(value).__name__} is not a number "
                    "or a string")


_NEEDS_QUOTES = frozenset(',"\r\n')
_PLAIN = frozenset((float, int, type(None)))  # the cells of a run's rows


def _cell(value) -> str:
    """:func:`format_value` as a CSV cell: quoted as the csv module quotes, where needed."""
    text = format_value(value)
    if _NEEDS_QUOTES.isdisjoint(text):
        return text
    return '"' + text.replace('"', '""') + '"'


class StatsWriter:
    """CSV writer of per-step statistics.

    Parameters
    ----------
    path : str or os.PathLike
        CSV file (``DIR/stats.csv``).
    columns : list of str
        Column names, in order; written as the header.
    enabled : bool
        True on the rank that writes (rank 0); on the others every method does nothing,
        so all ranks can call ``write`` unconditionally.
    mode : {"w", "a"}
        ``"w"`` starts a new file; ``"a"`` appends to an existing one (restart), whose
        header must equal ``columns`` (a new or empty file gets the header).
    flush_seconds : float
        Rows are flushed to the file when this much wall time has passed since the last
        flush (0: after every row).

    Raises
    ------
    ParsphError
        If the columns are empty or repeated, the file cannot be opened, or (mode "a")
        the existing header differs.
    """

    def __init__(self, path, columns: list[str], enabled: bool, mode: str = "w",
                 flush_seconds: float = 1.0):
        self.path = os.fspath(path)
        self.flush_seconds = float(flush_seconds)
        self._flushed = time.monotonic()
        self._rows = []  # rows written since the last flush, not yet formatted
        self.columns = [str(c) for c in columns]
        self._known = frozenset(self.columns)
        self.enabled = bool(enabled)
        self._fh = None
        if not self.columns:
            raise ParsphError(f"StatsWriter for {self.path}: no columns given; name at least one")
        repeated = sorted({c for c in self.columns if self.columns.count(c) > 1})
        if repeated:
            raise ParsphError(f"StatsWriter for {self.path}: columns {repeated} are repeated; "
                              "give each column once")
        if mode not in ("w", "a"):
            raise ParsphError(f"StatsWriter: mode must be 'w' or 'a', got {mode!r}")
        if not self.enabled:
            return
        write_header = True
        if mode == "a" and os.path.isfile(self.path) and os.path.getsize(self.path) > 0:
            with open(self.path, newline="", encoding="utf-8") as fh:
                header = next(csv.reader(fh), [])
            if header != self.columns:
                raise ParsphError(
                    f"cannot append to {self.path}: its columns {header} differ from "
                    f"{self.columns}; restart into a new output directory or move the old file"
                )
            write_header = False
        try:
            self._fh = open(self.path, mode, newline="", encoding="utf-8")
        except OSError as exc:
            raise ParsphError(f"cannot open {self.path} for writing ({exc}); check the output "
                              "directory and its permissions") from None
        self._csv = csv.writer(self._fh, lineterminator="\n")
        if write_header:
            self._csv.writerow(self.columns)
            self._fh.flush()

    def write(self, row: dict) -> None:
        """Append one row (flushed within ``flush_seconds``).

        Parameters
        ----------
        row : dict
            Column name -> value (number, string or None). Missing columns are left
            empty.

        Raises
        ------
        ValueError
            If ``row`` has keys that are not columns (checked on every rank).
        """
        if not self._known.issuperset(row):
            unknown = [k for k in row if k not in self._known]
            raise ValueError(f"stats row has unknown columns {unknown}; the columns of "
                             f"{self.path} are {self.columns} — add them when creating the "
                             "StatsWriter")
        if not self.enabled:
            return
        if self._fh is None:
            raise ParsphError(f"StatsWriter for {self.path} is closed; create a new one")
        values = list(map(row.get, self.columns))
        if not _PLAIN.issuperset(map(type, values)):
            for v in values:  # a value that cannot be written fails here, not at the flush
                format_value(v)
        self._rows.append(values)
        if time.monotonic() - self._flushed >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the rows so far to the file (rank 0; nothing elsewhere).

        Rows are formatted here, a second's at a time: formatted one by one between the
        steps' other work, a row of 53 cells had taken 30-60 us of a 2D coupled step."""
        if self._fh is None:
            return
        rows, self._rows = self._rows, []
        self._fh.write("".join([",".join([repr(v) if type(v) is float else _cell(v)
                                          for v in values]) + "\n" for values in rows]))
        self._fh.flush()
        self._flushed = time.monotonic()

    def close(self) -> None:
        """Write the rows left and close the file (a second call does nothing)."""
        if self._fh is not None:
            try:
                self.flush()
            finally:
                self._fh.close()
                self._fh = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def read_stats(path) -> dict[str, np.ndarray]:
    """Read a stats CSV back: column -> float array (empty cells are NaN).

    Parameters
    ----------
    path : str or os.PathLike
        ``stats.csv``.

    Returns
    -------
    dict of str to ndarray
        One float64 array per column; a column holding text is returned as strings.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ParsphError(f"{path}: no such file; give the stats.csv of a parsph run")
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ParsphError(f"{path} is empty; the run wrote no statistics yet")
        rows = list(reader)
    out = {}
    for j, name in enumerate(header):
        cells = [r[j] if j < len(r) else "" for r in rows]
        try:
            out[name] = np.array([float(c) if c != "" else np.nan for c in cells], dtype=np.float64)
        except ValueError:
            out[name] = np.array(cells, dtype=str)
    return out
