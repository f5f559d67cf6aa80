"""The ground motion of the ``aso`` scene: a synthetic three-component record, from a formula.

Not a recording: the records of the 2016 Kumamoto main shock (Mw 7.0, 16 April 2016,
01:25 JST) are not shipped here. This record is built to have their character at the
Aso-ohashi site (docs/aso.md, "The earthquake", for the published figures it matches):

- **peak**: the three-component (vector) peak ground acceleration is :data:`PGA_VECTOR`,
  that of K-NET Ozu (KMM005), the station nearest the site among the main shock's ten
  largest; the components in the ratio :data:`RATIOS` (along the path, across, up);
- **duration**: a Saragoni-Hart envelope e(t) = (t / tp)^2 exp(2 (1 - t / tp)), peak at
  tp = :data:`T_PEAK`, so the strong shaking lasts about as long as the rupture (large
  slip up to about 16 s, reaching the Aso caldera);
- **spectral content**: a sum of sinusoids at :data:`N_FREQ` log-spaced frequencies with
  a Kanai-Tajimi amplitude, predominant :data:`F_HORIZONTAL` (horizontal) and
  :data:`F_VERTICAL` (vertical), high-passed below :data:`F_LOW` (Clough-Penzien);
  phases frac(k (sqrt 5 - 1) / 2 + c sqrt 2) (no random numbers);
- a baseline correction: the velocity ends at zero.

Columns: time (s), then a_x along the path (up-slope positive), a_y across it, a_z up, in
m/s². Run it from the repository's root; ``--check`` compares with the shipped file::

    .venv/bin/python jobs/make_aso_record.py            # writes parsph/scenes/data/aso_record.csv
    .venv/bin/python jobs/make_aso_record.py --check    # exit 1 if it differs
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

DATA = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "parsph",
                                    "scenes", "data"))

DT, DURATION = 0.01, 40.0        # s
T_PEAK = 7.0                     # s: the envelope's peak
PGA_VECTOR = 6.69                # m/s^2: K-NET Ozu (KMM005), 669 gal, three components
RATIOS = (1.0, 0.75, 0.55)       # peaks along the path, across it, vertical
N_FREQ = 48                      # sinusoids per component, 0.15 .. 12 Hz
F_HORIZONTAL, F_VERTICAL = 1.2, 3.0   # Hz: predominant frequencies (Kanai-Tajimi f_g)
ZETA_G = 0.6                     # Kanai-Tajimi damping
F_LOW = 0.2                      # Hz: Clough-Penzien high-pass corner


def kanai_tajimi(f, fg, zeta=ZETA_G, f_low=F_LOW):
    """Amplitude (not power) of the Kanai-Tajimi spectrum times a Clough-Penzien high-pass."""
    r, rl = (f / fg) ** 2, (f / f_low) ** 2
    kt = (1 + 4 * zeta ** 2 * r) / ((1 - r) ** 2 + 4 * zeta ** 2 * r)
    cp = rl ** 2 / ((1 - rl) ** 2 + 4 * zeta ** 2 * rl)
    return np.sqrt(kt * cp)


def record():
    """``(t, a)``: times (s) and accelerations (m/s²), columns along, across, up."""
    t = np.round(np.arange(int(round(DURATION / DT)) + 1) * DT, 2)
    env = (t / T_PEAK) ** 2 * np.exp(2.0 * (1.0 - t / T_PEAK))
    f = np.geomspace(0.15, 12.0, N_FREQ)
    k = np.arange(1, N_FREQ + 1)
    cols = []
    for c, fg in enumerate((F_HORIZONTAL, F_HORIZONTAL, F_VERTICAL)):
        amp = kanai_tajimi(f, fg) * np.sqrt(f)  # equal power per log-frequency band
        phase = 2 * np.pi * np.mod(k * (np.sqrt(5.0) - 1) / 2 + c * np.sqrt(2.0), 1.0)
        a = env * (amp[:, None] * np.sin(2 * np.pi * f[:, None] * t + phase[:, None])).sum(0)
        v_end = np.trapz(a, t)
        a = a - v_end * env / np.trapz(env, t)  # the velocity ends at zero
        cols.append(RATIOS[c] * a / np.abs(a).max())
    a = np.array(cols).T
    a *= PGA_VECTOR / np.linalg.norm(a, axis=1).max()
    return t, np.round(a, 4) + 0.0


def response_spectrum(t, a, periods, zeta=0.05):
    """5 %-damped pseudo-acceleration (m/s²) of one component at ``periods`` (s):
    Newmark's average-acceleration integration of the oscillators, all periods at once."""
    dt = t[1] - t[0]
    w = 2 * np.pi / np.asarray(periods)
    u = np.zeros_like(w)
    v = np.zeros_like(w)
    acc = -a[0] - 2 * zeta * w * v - w ** 2 * u
    peak = np.zeros_like(w)
    k_eff = w ** 2 + 2 * zeta * w * 2 / dt + 4 / dt ** 2
    for i in range(1, len(t)):
        p = (-a[i] + (4 / dt ** 2) * u + (4 / dt) * v + acc
             + 2 * zeta * w * ((2 / dt) * u + v))
        un = p / k_eff
        vn = 2 * (un - u) / dt - v
        acc = 4 * (un - u) / dt ** 2 - 4 * v / dt - acc
        u, v = un, vn
        peak = np.maximum(peak, np.abs(u))
    return w ** 2 * peak


def character(t, a) -> dict:
    """What docs/aso.md quotes: peaks, velocity, durations, predominant periods."""
    out = {"pga_vector_ms2": float(np.linalg.norm(a, axis=1).max())}
    periods = np.geomspace(0.05, 5.0, 200)
    for c, name in enumerate(("along", "across", "up")):
        x = a[:, c]
        arias = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] ** 2 + x[:-1] ** 2) * np.diff(t))])
        t5, t95 = np.interp([0.05 * arias[-1], 0.95 * arias[-1]], arias, t)
        vel = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])
        sa = response_spectrum(t, x, periods)
        out.update({f"{name}_pga_ms2": float(np.abs(x).max()),
                    f"{name}_pga_time_s": float(t[np.argmax(np.abs(x))]),
                    f"{name}_pgv_ms": float(np.abs(vel).max()),
                    f"{name}_v_end_ms": float(vel[-1]),
                    f"{name}_d5_95_s": float(t95 - t5), f"{name}_t5_s": float(t5),
                    f"{name}_predominant_period_s": float(periods[np.argmax(sa)]),
                    f"{name}_sa_max_ms2": float(sa.max()),
                    f"{name}_arias_ms": float(np.pi / (2 * 9.81) * arias[-1])})
    return out


def csv_text(t, a) -> str:
    head = ("# Synthetic ground motion of the aso scene, NOT a recording of the 2016 Kumamoto\n"
            "# main shock: written by jobs/make_aso_record.py (docs/aso.md, 'The earthquake').\n"
            "# x along the path (up-slope positive), y across it, z up.\n"
            "time (s), a_x along the path (m/s2), a_y across (m/s2), a_z up (m/s2)\n")
    return head + "".join(f"{ti:.2f}, {r[0]:.4f}, {r[1]:.4f}, {r[2]:.4f}\n" for ti, r in zip(t, a))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=DATA, help="directory of aso_record.csv")
    parser.add_argument("--check", action="store_true",
                        help="compare with the file in --out instead of writing it")
    args = parser.parse_args(argv)
    t, a = record()
    text = csv_text(t, a)
    path = os.path.join(args.out, "aso_record.csv")
    status = 0
    if args.check:
        with open(path, encoding="utf-8") as fh:
            same = fh.read() == text
        print(f"{path}: {'same' if same else 'DIFFERS'}")
        status = int(not same)
    else:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(text)
        print(f"wrote {path}")
    for key, value in character(t, a).items():
        print(f"  {key} = {value:.3f}")
    return status


if __name__ == "__main__":
    sys.exit(main())
