"""``DIR/triaxial.csv`` of a drained triaxial run (paper section 6.1, Figs. 4-5).

The TLSPH stage computes the specimen averages every step when ``solid.triaxial_csv`` is
true and puts them in ``stats.csv`` (columns ``axial_strain, p_eff, q, spec_volume, M``);
it also writes ``DIR/triaxial.csv`` directly when the driver tells the stage its output
directory (``ctx.out``); ``sigma_axial`` (the specimen's mean axial Cauchy stress,
compression positive, Pa: the platen force per area of a specimen in equilibrium) is
in stats.csv only. This module writes the same file from ``stats.csv``::

    python -m parsph.solid.triaxial DIR

Columns: ``t`` (s), ``axial_strain`` (compression positive, 1 - mean F_zz), ``p`` (mean
effective stress p', Pa, compression positive), ``q`` (von Mises stress, Pa), ``v``
(specific volume), ``M`` (critical state ratio of the material).
"""
from __future__ import annotations

import csv
import os
import sys

HEADER = ("t", "axial_strain", "p", "q", "v", "M")


def write_from_stats(out: str) -> str:
    """Write ``out/triaxial.csv`` from ``out/stats.csv``; returns its path.

    Raises
    ------
    ValueError
        If stats.csv has no triaxial columns (the scene did not set solid.triaxial_csv).
    """
    src = os.path.join(out, "stats.csv")
    with open(src, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if rows and "p_eff" not in rows[0]:
        raise ValueError(f"{src} has no triaxial columns; run the scene with "
                         f"solid.triaxial_csv = true")
    path = os.path.join(out, "triaxial.csv")
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for r in rows:
            w.writerow((r["time"], r["axial_strain"], r["p_eff"], r["q"], r["spec_volume"],
                        r["M"]))
    return path


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m parsph.solid.triaxial DIR")
    print(write_from_stats(sys.argv[1]))
