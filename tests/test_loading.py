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


def test_aso_record_is_its_generator_and_has_its_character():
    """The shipped ``aso_record.csv`` is ``jobs/make_aso_record.py``'s output byte for byte
    and has the character docs/aso.md quotes: a three-component peak of 6.69 m/s² (K-NET
    Ozu's 669 gal), peaks in the ratio 1 : 0.75 : 0.55 (along the path, across, up), a
    5-95 % Arias duration of 12.4-12.6 s, the horizontal 5 %-damped spectra peaking at
    0.9-1.1 s and the vertical at 0.36 s, and no velocity left at the end. Read back
    through the scene loader's reader (4-decimal values: 1e-4 m/s² apart at most)."""
    import os

    from jobs import make_aso_record as gen

    path = os.path.join(gen.DATA, "aso_record.csv")
    t, a = gen.record()
    with open(path, encoding="utf-8") as fh:
        assert fh.read() == gen.csv_text(t, a)
    rec = read_record(path, 3)
    assert np.abs(rec.a - a).max() < 1e-12
    c = gen.character(rec.t, rec.a)
    assert c["pga_vector_ms2"] == pytest.approx(6.69, abs=1e-3)
    assert c["across_pga_ms2"] / c["along_pga_ms2"] == pytest.approx(0.75, abs=0.01)
    assert c["up_pga_ms2"] / c["along_pga_ms2"] == pytest.approx(0.55, abs=0.01)
    for name in ("along", "across", "up"):
        assert 12.3 < c[f"{name}_d5_95_s"] < 12.7
        assert abs(c[f"{name}_v_end_ms"]) < 1e-3
    assert 0.9 <= c["along_predominant_period_s"] <= 1.15
    assert 0.9 <= c["across_predominant_period_s"] <= 1.15
    assert c["up_predominant_period_s"] == pytest.approx(0.357, abs=0.01)
