"""Earthquake records: parsing, units, interpolation, and bad records refused clearly."""
import numpy as np
import pytest

from parsph.errors import SceneError
from parsph.scene.loading import G0, read_record
from parsph.core.context import Context
from parsph.scene.loader import load_scene
from tests.scenes import MOVING_2D, write

GOOD = "# a test record\ntime (s), a_x (gal), a_y (m/s2)\n0.0, 0, 0\n0.1, 100, 1\n0.3, -100, 3\n"


def test_parse_units_and_interpolate(tmp_path):
    rec = read_record(write(tmp_path, GOOD, "r.csv"), 2)
    assert np.allclose(rec.a[1], [1.0, 1.0])  # 100 gal = 1 m/s^2
    assert np.allclose(rec.at(0.05), [0.5, 0.5])
    assert np.allclose(rec.at(0.2), [0.0, 2.0])
    assert np.allclose(rec.at(0.31), [0.0, 0.0])  # after the record: zero
    assert np.allclose(rec.at(-0.1), [0.0, 0.0])
    g3 = read_record(write(tmp_path, "t [s], x [g], y [g], z [g]\n0, 1, 0, 0\n1, 1, 0, 0.5\n",
                           "g.csv"), 3)
    assert np.allclose(g3.at(1.0), [G0, 0.0, 0.5 * G0])


BAD = [
    ("time (s), a_x (gal)\n0, 0\n0.1, 1\n", "needs 2"),
    ("time (s), a_x (gal), a_y (gal)\n0, 0, 0\n0.1, 1\n", "row 2 has 2 values"),
    ("time (s), a_x (gal), a_y (gal)\n0, 0, 0\n0.1, nan, 0\n", "NaN"),
    ("time (s), a_x (gal), a_y (gal)\n0, 0, 0\n0.2, 1, 0\n0.1, 1, 0\n", "not increasing"),
    ("time (s), a_x (gal), a_y (gal)\n0, 0, 0\n0.1, x, 0\n", "not a number"),
    ("time, a_x (gal), a_y (gal)\n0, 0, 0\n0.1, 1, 0\n", "gives no unit"),
    ("time (ms), a_x (gal), a_y (gal)\n0, 0, 0\n0.1, 1, 0\n", "seconds"),
    ("time (s), a_x (furlong), a_y (gal)\n0, 0, 0\n0.1, 1, 0\n", "unknown acceleration unit"),
    ("", "needs a header"),
]


@pytest.mark.parametrize("text,words", BAD, ids=[w for _, w in BAD])
def test_bad_records_refused(tmp_path, text, words):
    with pytest.raises(SceneError, match=words):
        read_record(write(tmp_path, text, "bad.csv"), 2)


def test_scene_with_record_and_body_acceleration(tmp_path):
    write(tmp_path, GOOD, "quake.csv")
    text = MOVING_2D + '\n[loading]\nrecord = "quake.csv"\nscale = 2.0\nstart_time = 1.0\n'
    scene = load_scene(write(tmp_path, text))
    ctx = Context(scene=scene, comm=None, particles=None, box=None, dim=2, d=0.05, h=0.06,
                  radius=0.12)
    assert np.allclose(ctx.body_acceleration(0.5), [0.0, -9.81])  # before the record starts
    # ground frame: g - s a_ground(t - t0)
    assert np.allclose(ctx.body_acceleration(1.2), [0.0 - 2 * 0.0, -9.81 - 2 * 2.0])
    missing = MOVING_2D + '\n[loading]\nrecord = "nowhere.csv"\n'
    with pytest.raises(SceneError, match="loading.record.*nowhere.csv"):
        load_scene(write(tmp_path, missing, "m.toml"))
