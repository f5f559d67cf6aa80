"""``parsph plot DIR``: render frames of ``particles.h5`` to PNG with matplotlib.

One PNG per frame, ``OUT/frame_NNNNNN.png``, holding one panel per colouring:

- 2D: one scatter panel per colouring, aspect equal, marker size equal to the particle
  spacing (root attribute ``particle_size``, m; estimated from the point cloud when
  absent). Panels are stacked vertically for wide domains, side by side for tall ones.
- 3D: two rows of panels, a side view (x–z, nearer particles, smaller y, drawn on top)
  and a top view (x–y, higher particles on top), one column per colouring.

Colourings: ``phase`` (solid / fluid / wall), ``speed`` (|v|, m/s),
``eps_p`` (-), ``p`` (Pa), ``porosity`` (-), ``rank``, or any other per-particle
dataset of the file (a vector field is shown by its magnitude). Every panel has a
colourbar with units (discrete for ``phase``). Wall particles are
always grey and left out of the colour range. The title gives the scene, the time (s),
the step and the particle count.

matplotlib is used through its object API with the Agg canvas (no pyplot, so no GUI
backend and no global state is touched); importing this module is cheap, matplotlib is
imported on the first call.
"""
from __future__ import annotations

import os

import numpy as np

from parsph.errors import ParsphError
from parsph.io.hdf5 import (PHASE_FLUID, PHASE_SOLID, PHASE_WALL, _index, _pick, frame_name,
                            open_run, resolve_path)

WALL_GREY = "#9e9e9e"
PHASE_COLOURS = {PHASE_SOLID: "#a0522d", PHASE_FLUID: "#1f77b4", PHASE_WALL: WALL_GREY}
PHASE_NAMES = {PHASE_SOLID: "solid", PHASE_FLUID: "fluid", PHASE_WALL: "wall"}

#: Colourbar labels (with units) of known colourings.
LABELS = {
    "speed": "speed |v| (m/s)",
    "eps_p": "plastic strain ε_p (–)",
    "p": "pressure p (Pa)",
    "porosity": "porosity n (–)",
    "rho": "density ρ (kg/m³)",
    "rank": "MPI rank",
    "id": "particle id",
    "v": "speed |v| (m/s)",
    "x": "|x| (m)",
}
CMAPS = {"speed": "viridis", "eps_p": "magma_r", "p": "coolwarm", "porosity": "cividis",
         "rank": "tab10"}


def _values(data: dict, name: str, fname: str, step: int) -> np.ndarray:
    """The per-particle values of a colouring."""
    key = "v" if name == "speed" else name
    if key not in data:
        names = sorted(["speed"] + [k for k, a in data.items() if a.ndim >= 1])
        raise ParsphError(f"cannot colour by {name!r}: frame {step} of {fname} has no field "
                          f"{key!r}; choose from {names}")
    name = key
    a = np.asarray(data[name], dtype=np.float64)
    if a.ndim == 2:
        return np.linalg.norm(a, axis=1)
    if a.ndim > 2:
        return np.linalg.norm(a.reshape(a.shape[0], -1), axis=1)
    return a


def _spacing(attrs: dict, x: np.ndarray) -> float:
    """Particle spacing (m): the root attribute, else an estimate from the bounding box."""
    d = attrs.get("particle_size")
    try:
        d = float(d)
        if d > 0 and np.isfinite(d):
            return d
    except (TypeError, ValueError):
        pass
    n, dim = x.shape
    ext = np.ptp(x, axis=0)
    ext = ext[ext > 0]
    if n < 2 or ext.size == 0:
        return 1.0 if ext.size == 0 else float(ext.max()) / 10
    return float(np.prod(ext) / n) ** (1.0 / ext.size)


def _marker_area(ax, d: float) -> float:
    """Marker area (pt²) of a disc of diameter ``d`` (m) in the axes' data units."""
    fig = ax.figure
    p0, p1 = ax.transData.transform([(0.0, 0.0), (d, 0.0)])
    diameter_pt = abs(p1[0] - p0[0]) * 72.0 / fig.dpi
    return max(diameter_pt, 0.3) ** 2


def _panel(fig, ax, xy, depth, values, phase, name, d, cbar: bool):
    """Scatter one panel; returns the scatter artists (to resize markers later)."""
    from matplotlib.colors import ListedColormap

    order = np.argsort(depth, kind="stable") if depth is not None else np.arange(len(xy))
    xy, phase = xy[order], phase[order]
    values = None if values is None else values[order]
    wall = phase == PHASE_WALL
    artists = []
    if wall.any():
        artists.append(ax.scatter(xy[wall, 0], xy[wall, 1], s=1, c=WALL_GREY, linewidths=0,
                                  rasterized=True, zorder=1))
    inner = ~wall
    if name == "phase":
        from matplotlib.colors import BoundaryNorm

        cmap = ListedColormap([PHASE_COLOURS[k] for k in sorted(PHASE_NAMES)])
        norm = BoundaryNorm([-0.5, 0.5, 1.5, 2.5], cmap.N)
        sc = ax.scatter(xy[inner, 0], xy[inner, 1], s=1, c=phase[inner], cmap=cmap, norm=norm,
                        linewidths=0, rasterized=True, zorder=2)
        artists.append(sc)
        if cbar:  # a discrete colourbar keeps the panels aligned with the others
            cb = fig.colorbar(sc, ax=ax, shrink=0.9, ticks=sorted(PHASE_NAMES))
            cb.ax.set_yticklabels([PHASE_NAMES[k] for k in sorted(PHASE_NAMES)])
            cb.set_label("phase")
        return artists
    vals = values[inner]
    finite = vals[np.isfinite(vals)]
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if vmax <= vmin:
        vmax = vmin + (abs(vmin) * 1e-6 or 1.0)
    cmap = CMAPS.get(name, "viridis")
    if name == "rank":
        import matplotlib

        cmap = ListedColormap(matplotlib.colormaps["tab10"].colors)
        vmin, vmax = -0.5, 9.5
    sc = ax.scatter(xy[inner, 0], xy[inner, 1], s=1, c=vals, cmap=cmap, vmin=vmin, vmax=vmax,
                    linewidths=0, rasterized=True, zorder=2)
    artists.append(sc)
    if cbar:
        fig.colorbar(sc, ax=ax, label=LABELS.get(name, name), shrink=0.9)
    return artists


def _limits(a: np.ndarray, d: float) -> tuple[float, float]:
    lo, hi = float(a.min()), float(a.max())
    pad = max(d, 0.02 * (hi - lo))
    return lo - pad, hi + pad


def render_frame(data: dict, attrs: dict, time: float, step: int, fname: str, png: str,
                 color_by=("phase", "speed", "eps_p"), dpi: int = 110) -> str:
    """Render one frame to ``png``.

    Parameters
    ----------
    data : dict of str to ndarray
        The frame's datasets (at least ``x``; ``phase`` missing means all solid).
    attrs : dict
        Root attributes of the run (``dim``, ``particle_size`` in m, ``scene``).
    time : float
        Simulated time (s), for the title.
    step : int
        Step number, for the title.
    fname : str
        Source file, named in error messages.
    png : str
        Output path.
    color_by : sequence of str
        Colourings, one panel (2D) or one column (3D) each.
    dpi : int
        Resolution of the PNG.

    Returns
    -------
    str
        ``png``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x = np.asarray(data.get("x", np.zeros((0, 2))), dtype=np.float64)
    if x.ndim != 2 or x.shape[0] == 0:
        raise ParsphError(f"frame {step} of {fname} has no particles; nothing to plot — pick "
                          "another frame (frames='all' or a list of steps)")
    n, dim = x.shape
    if dim not in (2, 3):
        raise ParsphError(f"frame {step} of {fname}: positions have {dim} columns; only 2D and "
                          "3D runs can be plotted")
    color_by = [color_by] if isinstance(color_by, str) else list(color_by)
    if not color_by:
        raise ParsphError("plot: color_by is empty; give at least one of 'phase', 'speed', 'eps_p'")
    phase = np.asarray(data.get("phase", np.zeros(n)), dtype=np.int64)
    values = {c: (None if c == "phase" else _values(data, c, fname, step)) for c in color_by}
    d = _spacing(attrs, x)
    k = len(color_by)

    if dim == 2:
        (x0, x1), (y0, y1) = _limits(x[:, 0], d), _limits(x[:, 1], d)
        aspect = (y1 - y0) / (x1 - x0)
        if aspect <= 1.0:  # wide: panels stacked
            w = 9.0
            ph = float(np.clip(0.72 * w * aspect, 1.2, 5.0)) + 0.5
            fig = Figure(figsize=(w, ph * k + 0.6), dpi=dpi, layout="constrained")
            axes = fig.subplots(k, 1, squeeze=False)[:, 0]
        else:  # tall: side by side
            h = 6.0
            pw = float(np.clip(0.8 * h / aspect, 1.5, 5.0)) + 1.0
            fig = Figure(figsize=(pw * k, h), dpi=dpi, layout="constrained")
            axes = fig.subplots(1, k, squeeze=False)[0]
        views = [(axes, (0, 1), None, ("x (m)", "y (m)"))]
    else:
        (x0, x1) = _limits(x[:, 0], d)
        zr, yr = np.ptp(x[:, 2]) + 2 * d, np.ptp(x[:, 1]) + 2 * d
        aspect = float(np.clip(max(zr, yr) / (x1 - x0), 0.25, 1.5))
        pw = 4.6 if k > 1 else 7.0
        fig = Figure(figsize=(pw * k, 2 * (pw * 0.8 * aspect + 0.8) + 0.6), dpi=dpi,
                     layout="constrained")
        grid = fig.subplots(2, k, squeeze=False)
        # side view from −y: nearer (smaller y) on top -> draw in order of decreasing y
        views = [(grid[0], (0, 2), -x[:, 1], ("x (m)", "z (m)  [side view]")),
                 (grid[1], (0, 1), x[:, 2], ("x (m)", "y (m)  [top view]"))]
    FigureCanvasAgg(fig)

    scatters = []
    for axes, (i, j), depth, (xl, yl) in views:
        for ax, name in zip(axes, color_by):
            arts = _panel(fig, ax, x[:, [i, j]], depth, values[name], phase, name, d, cbar=True)
            ax.set_xlim(*_limits(x[:, i], d))
            ax.set_ylim(*_limits(x[:, j], d))
            ax.set_aspect("equal", adjustable="box")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_title(name if name != "speed" else "speed", fontsize="medium")
            scatters.append((ax, arts))
    scene = attrs.get("scene") or attrs.get("scene_name") or ""
    title = f"{scene + ' — ' if scene else ''}t = {time:.6g} s  (step {step}, {n} particles)"
    fig.suptitle(title)
    fig.canvas.draw()  # settle the layout, then size markers to the particle spacing
    for ax, arts in scatters:
        area = _marker_area(ax, d)
        for a in arts:
            a.set_sizes([area])
    os.makedirs(os.path.dirname(os.path.abspath(png)), exist_ok=True)
    fig.savefig(png, dpi=dpi)
    return png


def plot_run(run_dir, out=None, color_by=("phase", "speed", "eps_p"), frames="last",
             dpi: int = 110) -> list[str]:
    """Render frames of a run to PNG files.

    Parameters
    ----------
    run_dir : str or os.PathLike
        Run directory (holding ``particles.h5``) or the HDF5 file itself.
    out : str or os.PathLike, optional
        Output directory; default ``<run directory>/plots``. Created if needed.
    color_by : sequence of str
        Colourings: ``phase``, ``speed`` (m/s), ``eps_p`` (-), ``p`` (Pa), ``porosity``,
        ``rank`` or any per-particle dataset.
    frames : "last", "all", int or list of int
        Steps to render.
    dpi : int
        Resolution of the PNGs.

    Returns
    -------
    list of str
        Paths of the PNG files written, one per frame (``frame_NNNNNN.png``).

    Raises
    ------
    ParsphError
        If the file is missing or not a parsph HDF5 file, a requested step does not
        exist, a frame is empty or a colouring is unknown.
    """
    fname = resolve_path(run_dir)
    out = os.path.join(os.path.dirname(os.path.abspath(fname)), "plots") if out is None else os.fspath(out)
    with open_run(fname) as f:
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
        for key, v in list(attrs.items()):
            if isinstance(v, bytes):
                attrs[key] = v.decode(errors="replace")
        index = _index(f)
        if isinstance(frames, str) and frames == "all":
            if not index:
                _pick(fname, index, "last")  # raises: no frame yet
            chosen = index
        elif isinstance(frames, str) or frames is None:
            chosen = [_pick(fname, index, frames)]
        elif isinstance(frames, (int, np.integer)):
            chosen = [_pick(fname, index, int(frames))]
        else:
            chosen = [_pick(fname, index, int(s)) for s in frames]
        paths = []
        for fr in chosen:
            grp = f[frame_name(fr.step)]
            data = {k: d[()] for k, d in grp.items() if hasattr(d, "shape")}
            png = os.path.join(out, f"frame_{fr.step:06d}.png")
            paths.append(render_frame(data, attrs, fr.time, fr.step, fname, png,
                                      color_by=color_by, dpi=dpi))
    return paths
