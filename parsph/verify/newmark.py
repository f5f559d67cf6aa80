r"""Newmark's (1965) rigid sliding block: the permanent slip of a block on an incline
under a ground-acceleration record, the reference of the earthquake loading
(docs/loading.md, ``newmark_block``).

A rigid block on a plane inclined at :math:`\theta`, Coulomb friction :math:`\mu`, rests
while the ground's acceleration along the slope, :math:`a(t)` (positive uphill: the
direction whose inertial force, :math:`-a`, pushes the block downhill), stays below the
yield acceleration

.. math:: a_y = g(\mu\cos\theta - \sin\theta).

Once it is exceeded, the block slides downhill relative to the ground at
:math:`\dot v = a(t) - a_y` until its relative velocity :math:`v` returns to zero; then it
sticks again. The slip is :math:`\int v\,dt`. Sliding is one-directional (downhill): the
record must not pull the block uphill, :math:`a < -g(\mu\cos\theta + \sin\theta)`
(:func:`newmark_slip` refuses such a record).

The record is linear between its samples and zero outside them, as parsph reads it
(:class:`parsph.scene.loading.Record`): on each interval :math:`v` is then a quadratic
and the slip a cubic of time, integrated exactly, with the instants where sliding starts
(the record crosses :math:`a_y`) and stops (:math:`v = 0`) solved in closed form. After the
record's end the block decelerates at :math:`a_y` and slips :math:`v^2 / (2 a_y)` more.
"""
from __future__ import annotations

import math

import numpy as np

from parsph.errors import ParsphError

__all__ = ["newmark_slip", "rectangular_pulse_slip", "yield_acceleration"]


def yield_acceleration(g: float, mu: float, theta: float) -> float:
    r""":math:`a_y = g(\mu\cos\theta - \sin\theta)` (m/s²): the least ground acceleration
    along the slope (uphill) that makes a block of friction ``mu`` on a slope ``theta``
    (radians) slide; ``g`` = :math:`|\mathbf g|`."""
    return g * (mu * math.cos(theta) - math.sin(theta))


def rectangular_pulse_slip(amplitude: float, duration: float, a_y: float) -> float:
    r"""The slip (m) of one rectangular pulse of ``amplitude`` :math:`A > a_y` lasting
    ``duration`` :math:`T`, by hand: :math:`v` grows at :math:`A - a_y` to
    :math:`(A - a_y)T`, then falls at :math:`a_y`, so
    :math:`s = \tfrac12 (A - a_y) T^2 + \tfrac12 (A - a_y)^2 T^2 / a_y = A (A - a_y) T^2 /
    (2 a_y)` (zero for :math:`A \le a_y`)."""
    if amplitude <= a_y:
        return 0.0
    return amplitude * (amplitude - a_y) * duration ** 2 / (2.0 * a_y)


def _roots(c2, c1, c0, lo, hi):
    """The real roots of ``c2 u^2 + c1 u + c0`` in ``(lo, hi]``, ascending."""
    if c2 == 0.0:
        r = [-c0 / c1] if c1 != 0.0 else []
    else:
        disc = c1 * c1 - 4.0 * c2 * c0
        if disc < 0.0:
            return []
        s = math.sqrt(disc)
        q = -0.5 * (c1 + math.copysign(s, c1))  # no cancellation
        r = [q / c2, c0 / q] if q != 0.0 else [0.0]
    return sorted(u for u in r if lo < u <= hi)


def newmark_slip(t, a, a_y: float, a_up: float = math.inf) -> dict:
    r"""The permanent downhill slip of Newmark's rigid block under a record.

    Parameters
    ----------
    t : array_like
        Sample times (s), strictly increasing.
    a : array_like
        The ground's acceleration along the slope at ``t`` (m/s², positive uphill), linear
        between samples, zero before the first and after the last.
    a_y : float
        Yield acceleration (m/s², > 0; :func:`yield_acceleration`).
    a_up : float
        The ground acceleration downhill (m/s², > 0) past which the block would slide
        uphill, :math:`g(\mu\cos\theta + \sin\theta)`; a record that reaches it is refused
        (this integration is one-directional). Default: never checked.

    Returns
    -------
    dict
        ``slip`` (m), ``peak_velocity`` (m/s, relative), ``episodes``: a list of
        ``(start, stop, slip)`` of each sliding episode (s, s, m).
    """
    t = np.asarray(t, dtype=float)
    a = np.asarray(a, dtype=float)
    if not a_y > 0.0:
        raise ParsphError(f"Newmark block: yield acceleration {a_y} m/s^2 is not positive: "
                          "the block slides under gravity alone (mu <= tan(theta))")
    if t.ndim != 1 or t.shape != a.shape or len(t) < 2 or np.any(np.diff(t) <= 0.0):
        raise ParsphError("Newmark block: t and a must be 1D of equal length >= 2, t "
                          "strictly increasing")
    if np.any(-a >= a_up):
        raise ParsphError(f"Newmark block: the record reaches {float(-a.min()):.4g} m/s^2 "
                          f"downhill, past {a_up:.4g}: the block would slide uphill, which "
                          "this one-directional integration leaves out")
    v = 0.0  # relative velocity (m/s), downhill
    slip = 0.0
    peak = 0.0
    episodes = []
    start = base = 0.0
    for k in range(len(t) - 1):  # zero before the record: at rest until it starts
        h = t[k + 1] - t[k]
        f0 = a[k] - a_y
        kk = (a[k + 1] - a[k]) / h  # the sliding block's acceleration is f0 + kk u
        u = 0.0
        while u < h:
            f = f0 + kk * u
            if v == 0.0:  # stuck: slides once f > 0, now or where the linear f crosses 0
                if not (f > 0.0 or (f == 0.0 and kk > 0.0)):
                    if kk <= 0.0 or -f / kk >= h - u:
                        break
                    u, f = u - f / kk, 0.0
                start, base = t[k] + u, slip
            # sliding: v(w) = v + f w + kk w^2 / 2 until it is zero again
            rest = h - u
            stop = _roots(0.5 * kk, f, v, 0.0, rest)
            w = stop[0] if stop else rest
            if kk < 0.0 and 0.0 < -f / kk < w:  # the largest v inside this stretch
                peak = max(peak, v - 0.5 * f * f / kk)
            slip += v * w + 0.5 * f * w * w + kk * w ** 3 / 6.0
            v = 0.0 if stop else max(v + f * w + 0.5 * kk * w * w, 0.0)
            peak = max(peak, v)
            u += w
            if stop:
                episodes.append((start, t[k] + u, slip - base))
    if v > 0.0:  # after the record: decelerates at a_y
        slip += v * v / (2.0 * a_y)
        episodes.append((start, t[-1] + v / a_y, slip - base))
    return {"slip": slip, "peak_velocity": peak, "episodes": episodes}
