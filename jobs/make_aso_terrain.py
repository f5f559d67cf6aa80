"""The terrain of the ``aso`` scene: three ESRI ASCII grids, written from a formula.

A strip along the path of the 2016 Aso-ohashi landslide (docs/aso.md, "Geometry", for the
published numbers each segment matches), x pointing up the path, y across it (the scene
is periodic in y: a slice of a slope that is the same across the path). Three surfaces,
each a layer boundary (m above sea level, on the same nodes):

- ``aso_surface.asc``: the ground S(x, y);
- ``aso_soil2_base.asc``: the base B of soil 2, the weakened mass under the source area:
  B = S - t(x), t = T sin^2(pi s^p), s = (x - x0) / (x1 - x0) between x0 and x1 (its
  deepest point at s = 0.6, towards the crown), 0 elsewhere (B = S outside the source);
- ``aso_soil1_base.asc``: the base of soil 1, D1(x) under B: 32 m under the slope,
  thinning to 8 m across the gorge (the Kurokawa cut it into rock).

The scene puts soil 2 between B and S, soil 1 between the soil-1 base and B, then 16 m of
soil 3 and 32 m of fixed bedrock. No download and no random numbers: the same bytes on
every machine. Run it from the repository's root; ``--check`` compares with the shipped
files instead of writing::

    .venv/bin/python jobs/make_aso_terrain.py            # writes parsph/scenes/data/
    .venv/bin/python jobs/make_aso_terrain.py --check    # exit 1 if they differ
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

DATA = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "parsph",
                                    "scenes", "data"))

CELL = 8.0                      # m: node spacing of both grids
NX, NY = 121, 13                # x = 0 .. 960 m (up the path), y = 0 .. 96 m (across)
ROUND = 10.0                    # m: the corners of the profile are rounded over about this

#: the profile's vertices (x, z): m along the path, m above sea level (docs/aso.md)
PROFILE = (
    (0.0, 400.0),     # far bank of the Kurokawa gorge (its rim)
    (60.0, 400.0),    # far rim
    (140.0, 320.0),   # far gorge wall, 45 degrees down to the river
    (180.0, 320.0),   # the river bed, 40 m
    (260.0, 400.0),   # near gorge wall, 45 degrees up: the gorge is 80 m deep, 200 m rim to rim
    (570.0, 524.0),   # lower slope, 21.8 degrees (Route 57 crosses it)
    (790.0, 676.0),   # upper slope, 34.6 degrees
    (860.0, 729.0),   # the steeper zone under the crown, 37.1 degrees (the corner is
                      # rounded: the crown, at x = 860 m, is at 725 m)
    (940.0, 744.0),   # above the crown, 10 degrees up to the ridge
    (960.0, 744.0),
)
SOURCE = (560.0, 860.0)         # x range of soil 2 (the source area, up to the crown)
SOIL2_THICKNESS = 30.0          # T (m): largest (vertical) thickness of soil 2
SOIL2_PEAK = 0.6                # s of its deepest point (p = ln 0.5 / ln SOIL2_PEAK)
SOIL1 = (8.0, 32.0, 250.0, 330.0)  # soil 1: 8 m up to x = 250 m, 32 m from x = 330 m on


def _soft(u):
    """A corner rounded over about ROUND: ROUND ln(1 + e^(u / ROUND)) (-> max(u, 0))."""
    return ROUND * np.logaddexp(0.0, u / ROUND)


def profile(x):
    """Ground height (m) along the path: the polyline :data:`PROFILE` with its corners
    rounded, z0 + sum_k (s_k - s_(k-1)) soft(x - x_k) (slopes s_k between vertices)."""
    xs, zs = np.array(PROFILE).T
    slopes = np.diff(zs) / np.diff(xs)
    z = zs[0] + slopes[0] * (x - xs[0])
    for k in range(1, len(slopes)):
        z = z + (slopes[k] - slopes[k - 1]) * _soft(x - xs[k])
    return z


def soil2_thickness(x):
    """t(x) (m): T sin^2(pi s^p) over the source area, 0 elsewhere."""
    x0, x1 = SOURCE
    s = np.clip((x - x0) / (x1 - x0), 0.0, 1.0)
    p = np.log(0.5) / np.log(SOIL2_PEAK)
    return SOIL2_THICKNESS * np.sin(np.pi * s ** p) ** 2


def soil1_thickness(x):
    """D1(x) (m): thin across the gorge, thick under the slope (a smoothstep between)."""
    thin, thick, xa, xb = SOIL1
    u = np.clip((x - xa) / (xb - xa), 0.0, 1.0)
    return thin + (thick - thin) * u * u * (3.0 - 2.0 * u)


def grids():
    """``(x nodes, S, B, T)``: node heights (m, 2 decimals) of the ground, the base of soil
    2 and the base of soil 1, rows south (y = 0) first."""
    x = np.arange(NX) * CELL
    s = np.round(profile(x), 2)
    b = np.round(s - soil2_thickness(x), 2)
    t = np.round(b - soil1_thickness(x), 2)
    return x, np.tile(s, (NY, 1)), np.tile(b, (NY, 1)), np.tile(t, (NY, 1))


def ascii_grid(z) -> str:
    """An ESRI ASCII grid of the node heights ``z`` (rows south first), north row first."""
    head = (f"ncols {NX}\nnrows {NY}\nxllcorner 0.0\nyllcorner 0.0\ncellsize {CELL:g}\n"
            f"NODATA_value -9999\n")
    return head + "".join(" ".join(f"{v:.2f}" for v in row) + "\n" for row in z[::-1])


def summary(x, s, b) -> dict:
    """What docs/aso.md quotes: heights, slopes and lengths of the profile."""
    z, t = s[0], s[0] - b[0]
    slope = np.degrees(np.arctan(np.abs(np.gradient(z, x))))
    src = (x >= SOURCE[0]) & (x <= SOURCE[1])
    crown = float(np.interp(SOURCE[1], x, z))
    river = float(z.min())
    x_river = float(x[np.argmin(z)])
    path = np.hypot(np.diff(x), np.diff(z))
    along = float(path[(x[1:] > x_river) & (x[1:] <= SOURCE[1])].sum())
    area = float(np.trapz(t, x))
    return {
        "crown_m": crown, "river_m": river, "ridge_m": float(z.max()),
        "relief_crown_river_m": crown - river,
        "crown_to_river_horizontal_m": SOURCE[1] - x_river,
        "crown_to_river_along_surface_m": along,
        "source_mean_slope_deg": float(np.degrees(np.arctan(
            (crown - np.interp(SOURCE[0], x, z)) / (SOURCE[1] - SOURCE[0])))),
        "steepest_deg": float(slope.max()),
        "steepest_above_gorge_deg": float(slope[x > 300.0].max()),
        "source_length_along_surface_m": float(path[src[1:] & src[:-1]].sum()),
        "soil2_max_thickness_m": float(t.max()),
        "soil2_area_per_width_m2": area,
        "soil2_volume_140m_wide_m3": 140.0 * area,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=DATA, help="directory of the grids")
    parser.add_argument("--check", action="store_true",
                        help="compare with the files in --out instead of writing them")
    args = parser.parse_args(argv)
    x, s, b, t = grids()
    files = {"aso_surface.asc": ascii_grid(s), "aso_soil2_base.asc": ascii_grid(b),
             "aso_soil1_base.asc": ascii_grid(t)}
    status = 0
    for name, text in files.items():
        path = os.path.join(args.out, name)
        if args.check:
            with open(path, encoding="utf-8") as fh:
                same = fh.read() == text
            print(f"{path}: {'same' if same else 'DIFFERS'}")
            status |= not same
        else:
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(text)
            print(f"wrote {path}")
    for key, value in summary(x, s, b).items():
        print(f"  {key} = {value:.1f}")
    return status


if __name__ == "__main__":
    sys.exit(main())
