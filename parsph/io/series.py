"""``parsph plot DIR --series``: a run's time series in one PNG.

One column of panels over a shared time axis (s), drawn from ``DIR/stats.csv``
(:mod:`parsph.io.stats`): each panel of :data:`PANELS` whose columns the run wrote
(kinetic and elastic energy, run-out front, fluidised volume, largest speed, Krylov
iterations of the PPE and the viscous predictor, time step), and, when
``DIR/probes.csv`` exists, one panel per probe and field.

``probes.csv`` is a tidy table, one value per row::

    time,probe,point,field,value
    0.1,gauge,0,p,1520.5

``time`` in s, ``probe`` the probe's name, ``point`` the point's index along the probe
(0 for a single point), ``field`` the sampled quantity (vectors and tensors per
component, ``v_x``, ``sigma_xy``) and ``value`` its value (``nan``: no sample). A
probe's components share a panel (:func:`_group`). A probe of up to :data:`MAX_LINES`
points gets one line per point; a longer one (a line probe) its mean over the points
with the min–max band shaded.

matplotlib through its object API with the Agg canvas, as :mod:`parsph.io.plot`.
"""
from __future__ import annotations

import csv
import os
import warnings

import numpy as np

from parsph.errors import ParsphError
from parsph.io.stats import read_stats

#: Panels from stats.csv: (y label, ((column, legend label), ...), log scale when the
#: values span a factor of 10 or more).
PANELS = (
    ("energy (J)", (("kinetic_energy", "kinetic"), ("elastic_energy", "elastic")), False),
    ("front (m)", (("front", "run-out front"),), False),
    ("fluidised volume", (("fluidised_volume", "fluidised"),), False),
    ("max speed (m/s)", (("max_speed", "max |v|"),), False),
    ("Krylov iterations", (("ppe_iterations", "PPE"), ("visc_iterations", "viscous")), False),
    ("time step (s)", (("dt", "dt"),), True),
)
PROBE_COLUMNS = ("time", "probe", "point", "field", "value")
#: Probes with more points are drawn as mean and min–max band.
MAX_LINES = 6
#: Units of probe fields parsph samples (others are labelled by name).
UNITS = {"p": "Pa", "rho": "kg/m³", "eps_p": "–", "porosity": "–", "speed": "m/s", "v": "m/s",
         "nu": "m²/s", "mass": "kg", "kinetic_energy": "J", "depth": "m", "thickness": "m",
         "fluid_fraction": "–", "solid_fraction": "–", "fluidised_fraction": "–",
         "volume_fraction": "–"}
#: Units of vector and tensor fields whose components are probed (``v_x``, ``sigma_xy``).
PREFIX_UNITS = {"sigma": "Pa", "fraction": "–"}
#: Suffixes of the components of vectors and tensors.
COMPONENTS = {"x", "y", "z", "xx", "yy", "zz", "xy", "xz", "yz"}


def probe_series(path) -> dict:
    """A tidy ``probes.csv`` as one time series per probe, field and point.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file (columns ``time, probe, point, field, value``, any order).

    Returns
    -------
    dict
        ``{(probe, field): {point: (time array in s, value array)}}``, in order of first
        appearance, each series sorted by time; ``point`` is an int.

    Raises
    ------
    ParsphError
        If a column is missing or a cell is not a number, naming the file and the line.
    """
    path = os.fspath(path)
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        missing = [c for c in PROBE_COLUMNS if c not in header]
        if missing:
            raise ParsphError(f"{path}: columns {missing} missing; a probes table has the "
                              f"columns {', '.join(PROBE_COLUMNS)} (one value per row)")
        col = {c: header.index(c) for c in PROBE_COLUMNS}
        raw: dict = {}
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            try:
                t, value = float(row[col["time"]]), float(row[col["value"]])
                point = int(row[col["point"]])
                probe, field = row[col["probe"]].strip(), row[col["field"]].strip()
            except (ValueError, IndexError):
                raise ParsphError(f"{path}, line {line}: {row} is not a row of time, probe, "
                                  "point (integer), field, value (numbers where due)") from None
            raw.setdefault((probe, field), {}).setdefault(point, []).append((t, value))
    out = {}
    for key, points in raw.items():
        out[key] = {}
        for point in sorted(points):
            a = np.array(sorted(points[point], key=lambda tv: tv[0]), dtype=np.float64)
            out[key][point] = (a[:, 0], a[:, 1])
    return out


def _finite(y) -> bool:
    y = np.asarray(y, dtype=np.float64)
    return bool(np.isfinite(y).any())


def _stats_panels(stats: dict, dim: int | None) -> list:
    """Panels of stats.csv with data: ``[(None, ylabel, [(label, t, y)], log, [None, ...])]``
    (title, y label, lines, log scale, a min–max band per line)."""
    t = stats["time"]
    panels = []
    for ylabel, columns, log in PANELS:
        lines = []
        for column, label in columns:
            y = stats.get(column)
            if y is None or y.dtype.kind != "f" or not _finite(y):
                continue
            y = np.where(np.isfinite(y), y, np.nan)
            lines.append((label, t, y))
        if lines and log:
            values = np.concatenate([y[np.isfinite(y)] for _, _, y in lines])
            log = bool((values > 0).all() and values.max() >= 10 * values.min())
        if lines:
            if ylabel == "fluidised volume":
                ylabel += {2: " (m²)", 3: " (m³)"}.get(dim, "")
            panels.append((None, ylabel, lines, log, [None] * len(lines)))
    return panels


def _group(field: str) -> str:
    """The panel of a probe field: components of a vector or tensor share their field's
    (``v_x``, ``v_y`` -> ``v``), volumes share one and fractions one."""
    base, _, component = field.rpartition("_")
    if base and component in COMPONENTS:
        return base
    if field == "volume" or field.endswith("_volume"):
        return "volume"
    if field.endswith("_fraction"):
        return "fraction"
    return field


def _probe_panels(probes: dict, dim) -> list:
    """Panels of probes.csv, one per probe and field group (:func:`_group`):
    ``[(title, ylabel, [(label, t, y)], False, [band or None per line])]``."""
    groups: dict = {}
    for (probe, field), points in probes.items():
        groups.setdefault((probe, _group(field)), []).append((field, points))
    panels = []
    for (probe, group), fields in groups.items():
        unit = {"volume": {2: "m²", 3: "m³"}.get(dim, "")}.get(group) or UNITS.get(group) \
            or PREFIX_UNITS.get(group, "")
        lines, bands = [], []
        for field, points in fields:
            name = f"{field}, " if len(fields) > 1 else ""
            if len(points) <= MAX_LINES:
                for k, (t, y) in points.items():
                    label = f"{name}point {k}" if len(points) > 1 else field
                    lines.append((label, t, y))
                    bands.append(None)
                continue
            times = np.unique(np.concatenate([t for t, _ in points.values()]))
            grid = np.full((len(points), len(times)), np.nan)
            for i, (t, y) in enumerate(points.values()):
                grid[i, np.searchsorted(times, t)] = y
            with warnings.catch_warnings():  # a time with no value at any point: NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(grid, axis=0)
                bands.append((times, np.nanmin(grid, axis=0), np.nanmax(grid, axis=0)))
            lines.append((f"{name}mean of {len(points)} points", times, mean))
        what = group if len(fields) > 1 else fields[0][0]  # a lone field by its own name
        ylabel = f"{what} ({unit})" if unit else what
        panels.append((f"probe {probe}", ylabel, lines, False, bands))
    return panels


def _linear_axis(ax, lines) -> None:
    """Plain tick labels (no offset); a near-constant series gets a ±5 % range instead of
    one that magnifies its round-off."""
    ax.ticklabel_format(axis="y", useOffset=False)
    values = np.concatenate([np.asarray(y, float) for _, _, y in lines])
    values = values[np.isfinite(values)]
    if values.size:
        lo, hi = float(values.min()), float(values.max())
        if hi - lo <= 1e-9 * max(abs(hi), abs(lo)):
            pad = 0.05 * abs(hi) or 1.0
            ax.set_ylim(lo - pad, hi + pad)


def plot_series(run_dir, png=None, dpi: int = 110):
    """Draw a run's time series (stats.csv, and probes.csv if any) into one PNG.

    Parameters
    ----------
    run_dir : str or os.PathLike
        Run directory holding ``stats.csv`` (and maybe ``probes.csv``).
    png : str or os.PathLike, optional
        Output file; default ``run_dir/plots/series.png``. Its directory is created.
    dpi : int
        Resolution.

    Returns
    -------
    png : str
        The path written.
    lines : dict
        ``{"panel y label/line label": (x, y)}``: the data of every line drawn, read back
        from the figure (time in s; probe panels as ``"probe NAME: ylabel/label"``).

    Raises
    ------
    ParsphError
        If ``stats.csv`` is missing, empty or has no ``time`` column, or ``probes.csv``
        is malformed.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    run_dir = os.fspath(run_dir)
    path = os.path.join(run_dir, "stats.csv")
    if not os.path.isfile(path):
        raise ParsphError(f"{path}: no such file; give the directory of a run written by "
                          "`parsph run --out DIR` (it holds stats.csv)")
    stats = read_stats(path)
    t = stats.get("time")
    if t is None or t.dtype.kind != "f":
        raise ParsphError(f"{path} has no numeric 'time' column; it is not a parsph stats file")
    if len(t) == 0:
        raise ParsphError(f"{path} holds no step yet; wait for the run's first step")
    dim, name = None, os.path.basename(os.path.abspath(run_dir))
    if os.path.isfile(os.path.join(run_dir, "particles.h5")):
        from parsph.io.hdf5 import read_attrs

        attrs = read_attrs(run_dir)
        dim, name = attrs.get("dim"), attrs.get("scene") or name
    panels = _stats_panels(stats, dim)
    probes_path = os.path.join(run_dir, "probes.csv")
    if os.path.isfile(probes_path):
        panels += _probe_panels(probe_series(probes_path), dim)

    height = float(np.clip(30.0 / len(panels), 1.3, 1.9))  # inches per panel
    fig = Figure(figsize=(8.0, height * len(panels) + 0.8), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    lines_out = {}
    for ax, (title, ylabel, lines, log, bands) in zip(axes, panels):
        for i, ((label, x, y), band) in enumerate(zip(lines, bands)):
            if band is not None:
                ax.fill_between(band[0], band[1], band[2], color=f"C{i % 10}", alpha=0.2,
                                linewidth=0, label=f"{label}: min–max")
            (line,) = ax.plot(x, y, label=label, linewidth=1.2, color=f"C{i % 10}")
            key = f"{title}: {ylabel}/{label}" if title else f"{ylabel}/{label}"
            lines_out[key] = (np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float))
        if log:
            ax.set_yscale("log")
        else:
            _linear_axis(ax, lines)
        ax.set_ylabel(ylabel)
        if title:
            ax.set_title(title, fontsize="medium", loc="left")
        if len(lines) > 1 or any(b is not None for b in bands):
            ax.legend(fontsize="small", loc="best")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{name}: {len(t)} steps to t = {np.nanmax(t):.6g} s")
    png = os.path.join(run_dir, "plots", "series.png") if png is None else os.fspath(png)
    os.makedirs(os.path.dirname(os.path.abspath(png)), exist_ok=True)
    fig.savefig(png, dpi=dpi)
    return png, lines_out
