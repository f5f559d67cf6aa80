"""Newmark's (1965) sliding block: the rigid-block integration by hand, and the
reference of the ``newmark_block`` scene."""
import math
import os

import numpy as np
import pytest

from parsph.errors import ParsphError
from parsph.scene.loader import load_scene
from parsph.verify.newmark import newmark_slip, rectangular_pulse_slip, yield_acceleration
from parsph.verify.solid import newmark_reference

A_Y = 2.0  # m/s^2


def test_rectangular_pulse_by_hand():
    """A record of two samples at A is an exact rectangular pulse (zero outside it):
    v grows at A - a_y for T, then falls at a_y; s = A (A - a_y) T^2 / (2 a_y)."""
    out = newmark_slip([0.0, 0.2], [4.0, 4.0], A_Y)
    assert rectangular_pulse_slip(4.0, 0.2, A_Y) == pytest.approx(4.0 * 2.0 * 0.04 / 4.0)
    assert out["slip"] == pytest.approx(0.08, rel=1e-12)
    assert out["peak_velocity"] == pytest.approx(0.4, rel=1e-12)
    (start, stop, slip), = out["episodes"]
    assert (start, stop, slip) == pytest.approx((0.0, 0.4, 0.08), rel=1e-12)
    # below a_y, and at it exactly: no slip
    assert newmark_slip([0.0, 0.2], [1.99, 1.99], A_Y)["slip"] == 0.0
    assert newmark_slip([0.0, 0.2], [2.0, 2.0], A_Y)["slip"] == 0.0


def test_ramp_pulse_by_hand():
    """a = A t / T on [0, T], then zero: slides from t1 = a_y T / A, v(T) = (T - t1)(A -
    a_y) / 2, slip during the ramp A/(2T) [(T^3 - t1^3)/3 - t1^2 (T - t1)] - a_y (T -
    t1)^2 / 2, then v(T)^2 / (2 a_y): the crossing of a_y and the cubic slip of a linear
    interval."""
    A, T = 5.0, 0.3
    t1 = A_Y * T / A
    vT = (T - t1) * (A - A_Y) / 2.0
    exact = (A / (2.0 * T) * ((T ** 3 - t1 ** 3) / 3.0 - t1 ** 2 * (T - t1))
             - A_Y * (T - t1) ** 2 / 2.0 + vT ** 2 / (2.0 * A_Y))
    out = newmark_slip([0.0, T], [0.0, A], A_Y)
    assert out["slip"] == pytest.approx(exact, rel=1e-12)
    assert out["episodes"][0][0] == pytest.approx(t1, rel=1e-12)
    assert out["episodes"][0][1] == pytest.approx(T + vT / A_Y, rel=1e-12)


def test_pulses_that_stop_in_between_add_up():
    """Two rectangular pulses far enough apart for the block to stop between them slip
    the sum of their own slips; the slip does not depend on how finely the same pulse is
    sampled; a pulse below a_y in between changes nothing."""
    t = [0.0, 0.1, 0.100001, 0.5, 0.500001, 0.7, 0.700001, 1.0, 1.000001, 1.3]
    a = [3.0, 3.0, 0.0, 0.0, 1.5, 1.5, 0.0, 0.0, 5.0, 5.0]
    out = newmark_slip(t, a, A_Y)
    ramps = 0.000001  # the steps from one level to the next are ramps of 1 us: ~1e-5 rel.
    expect = rectangular_pulse_slip(3.0, 0.1, A_Y) + rectangular_pulse_slip(5.0, 0.3, A_Y)
    assert out["slip"] == pytest.approx(expect, rel=1e3 * ramps)
    assert len(out["episodes"]) == 2
    fine = np.linspace(0.0, 0.2, 101)
    assert newmark_slip(fine, np.full(101, 4.0), A_Y)["slip"] == pytest.approx(0.08, rel=1e-12)


def test_piecewise_exact_against_small_steps():
    """A random record (linear between its samples): the exact integration agrees with
    explicit stick-slip steps of 1e-5 s to their own O(dt) error."""
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 2.0, 41)
    a = rng.normal(0.0, 3.0, 41)
    dt = 1e-5
    f = np.interp(np.arange(0.0, 2.0, dt) + 0.5 * dt, t, a) - A_Y  # midpoints
    vel, slip, peak = 0.0, 0.0, 0.0
    for df in f * dt:  # 2e5 steps
        vel = max(vel + df, 0.0) if (vel > 0.0 or df > 0.0) else 0.0
        slip += vel * dt
        peak = max(peak, vel)
    slip += vel ** 2 / (2.0 * A_Y)
    exact = newmark_slip(t, a, A_Y)
    assert exact["slip"] > 0.01 and len(exact["episodes"]) >= 3
    assert exact["slip"] == pytest.approx(slip, rel=1e-3)  # O(dt / the episodes' length)
    assert exact["peak_velocity"] == pytest.approx(peak, rel=1e-3)


def test_bad_input_refused():
    with pytest.raises(ParsphError, match="not positive"):
        newmark_slip([0.0, 1.0], [1.0, 1.0], yield_acceleration(9.81, 0.2, math.radians(30)))
    with pytest.raises(ParsphError, match="uphill"):
        newmark_slip([0.0, 1.0], [-9.0, 0.0], A_Y, a_up=8.0)
    with pytest.raises(ParsphError, match="strictly increasing"):
        newmark_slip([0.0, 0.0], [1.0, 1.0], A_Y)


def test_scene_reference():
    """``newmark_block``: a_y = g (mu cos 8 - sin 8) with mu = 0.35; its strong record
    slips in two episodes (the 1.4 m/s^2 pulse stays below a_y), its half-scaled one not
    at all; a record shaking normal to the slope is refused."""
    scene = load_scene("newmark_block")
    ref = newmark_reference(scene)
    assert ref["a_y"] == pytest.approx(9.81 * (0.35 * math.cos(math.radians(8.0))
                                              - math.sin(math.radians(8.0))))
    assert ref["theta_deg"] == pytest.approx(8.0)
    assert len(ref["episodes"]) == 2 and 0.08 < ref["slip"] < 0.09
    assert newmark_reference(load_scene("newmark_block", ["loading.scale=0.5"]))["slip"] == 0.0
    assert newmark_reference(load_scene("newmark_block", ["loading.start_time=1.0"]))["episodes"][
        0][0] == pytest.approx(ref["episodes"][0][0] + 1.0)


def test_scene_reference_refuses_normal_shaking(tmp_path):
    from parsph.scene.loader import builtin_path

    src = os.path.dirname(builtin_path("newmark_block"))
    with open(os.path.join(src, "data", "newmark_pulses.csv")) as fh:
        lines = fh.read().replace(", 0.0\n", ", 0.5\n")
    rec = tmp_path / "normal.csv"
    rec.write_text(lines)
    scene = load_scene("newmark_block", [f"loading.record={str(rec)!r}"])
    with pytest.raises(ParsphError, match="zero y column"):
        newmark_reference(scene)
