"""Write slope.asc: the height map of a steep 1 m slope, an ESRI ASCII grid.

A 2.2 m long, 0.5 m wide strip (x east, y north, z up, metres): flat ground at z = 0 up to
x = 0.4 m, a 59-degree face rising to z = 1 m at x = 1.0 m, then a plateau to x = 2.2 m.
Run it in this directory: ``python make_slope.py``.
"""
import numpy as np

CELL = 0.05  # m between grid nodes
X = np.arange(0.0, 2.2 + CELL / 2, CELL)  # node x (west to east)
Y = np.arange(0.0, 0.5 + CELL / 2, CELL)  # node y (south to north)


def height(x):
    """Surface height (m) at x (m)."""
    return np.clip((x - 0.4) / 0.6, 0.0, 1.0)


def main(path="slope.asc"):
    z = np.tile(height(X), (len(Y), 1))  # rows south to north
    with open(path, "w") as fh:
        fh.write(f"ncols {len(X)}\nnrows {len(Y)}\nxllcorner 0.0\nyllcorner 0.0\n"
                 f"cellsize {CELL}\n")
        for row in z[::-1]:  # the file lists rows north to south
            fh.write(" ".join(f"{v:.4f}" for v in row) + "\n")
    print(f"wrote {path}: {len(X)} x {len(Y)} nodes, heights {z.min():.2f}..{z.max():.2f} m")


if __name__ == "__main__":
    main()
