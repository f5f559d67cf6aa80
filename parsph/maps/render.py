"""The maps as PNG pictures over a hillshade of the terrain (matplotlib, Agg canvas, rank 0).

Each raster ``NAME.tif`` becomes ``NAME.png``: the hillshade (sun from the north-west,
45° high) of the first frame's surface (``surface_initial.tif``; the last frame's for
the deposit thickness), grey, under the raster's values in colour (cells without
material, zero or NaN, left clear), with a colourbar in the raster's unit, axes in the
scene's x, y (m). A raster wider than :data:`MAX_PIXELS` cells is read at a stride from
its file, so a picture never holds more than about ``MAX_PIXELS²`` values.
"""
from __future__ import annotations

import math
import os

import numpy as np

from parsph.io.geotiff import read_raster

#: Cells drawn along a picture's longer side at most.
MAX_PIXELS = 1600
_CMAPS = {"deposit_thickness": "YlOrBr", "erosion_depth": "PuRd", "max_flow_depth": "YlGnBu",
          "max_speed": "magma_r", "arrival_time": "viridis", "surface_initial": "terrain",
          "surface_final": "terrain"}


def _hillshade(z: np.ndarray, cell: float) -> np.ndarray:
    from matplotlib.colors import LightSource

    filled = np.where(np.isfinite(z), z, np.nanmin(z) if np.isfinite(z).any() else 0.0)
    return LightSource(azdeg=315, altdeg=45).hillshade(filled, dx=cell, dy=cell)


def draw(out: str, name: str, title: str, unit: str, grid, stride: int, shade) -> str:
    """``out/NAME.png`` of ``out/NAME.tif`` over the hillshade ``shade``; returns its path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    values = read_raster(os.path.join(out, f"{name}.tif"), stride)
    terrain = name.startswith("surface_")
    shown = np.ma.masked_where(~np.isfinite(values) | ((values <= 0) & (not terrain)), values)
    extent = (grid.west, grid.east, grid.south, grid.north)
    aspect = (grid.north - grid.south) / (grid.east - grid.west)
    width = 7.0
    fig = Figure(figsize=(width, min(max(width * aspect, 0.6), 12.0) + 1.6), dpi=130,
                 layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.imshow(shade, cmap="gray", vmin=0.0, vmax=1.0, extent=extent, origin="upper",
              interpolation="nearest")
    if shown.count():
        im = ax.imshow(shown, cmap=_CMAPS.get(name, "viridis"), alpha=0.5 if terrain else 0.8,
                       extent=extent, origin="upper", interpolation="nearest")
        wide = aspect < 0.5
        fig.colorbar(im, ax=ax, label=f"{title} ({unit})", shrink=0.6 if wide else 0.9,
                     orientation="horizontal" if wide else "vertical")
    else:
        ax.text(0.5, 0.5, f"no {title} anywhere", transform=ax.transAxes, ha="center",
                va="center")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_title(f"{title} ({unit}); cells of {grid.cell:g} m" +
                 (f", every {stride}th drawn" if stride > 1 else ""))
    path = os.path.join(out, f"{name}.png")
    fig.savefig(path)
    return path


def draw_all(out: str, grid, rasters: dict) -> list[str]:
    """Every raster of ``rasters`` (stem -> (title, unit)) as a picture; their paths."""
    stride = max(1, math.ceil(max(grid.nx, grid.ny) / MAX_PIXELS))
    cell = grid.cell * stride
    before = _hillshade(read_raster(os.path.join(out, "surface_initial.tif"), stride), cell)
    after = _hillshade(read_raster(os.path.join(out, "surface_final.tif"), stride), cell)
    return [draw(out, name, title, unit, grid, stride,
                 after if name in ("deposit_thickness", "surface_final") else before)
            for name, (title, unit) in rasters.items()]
