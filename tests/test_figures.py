"""The pages' figures are the runs' own (jobs/figures.py): every figure README.md and
docs/*.md quote from docs/figures/ is the recorded value, and the recording works."""
import json
import os

import pytest

from jobs import figures


def test_every_quoted_figure_is_the_recorded_one():
    """Each ``<!--{NAME.KEY:FORMAT}-->VALUE<!--/-->`` shows its record's value; rewrite
    with ``python jobs/figures.py`` after a record changed (never by hand)."""
    records = figures.load()
    quoted = 0
    for page in figures.pages():
        with open(os.path.join(figures.ROOT, page), encoding="utf-8") as fh:
            text = fh.read()
        quoted += len(figures.MARK.findall(text))
        _, differ = figures.render(text, records)
        assert not differ, f"{page}: {differ}; run python jobs/figures.py"
    assert quoted >= 30  # the README's and docs' headline figures are quoted
    for name, rec in records.items():
        assert rec["command"], f"docs/figures/{name}.json: no command to remake it"


def test_records_are_written_printed_and_kept_from_more_ranks(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PARSPH_FIGURES", str(tmp_path))
    figures.record("demo.a", {"x": 1.234567891, "n": 3, "l": [0.5, float("nan")]}, ranks=2,
                   command="cmd")
    assert capsys.readouterr().out == "figures demo.a: x = 1.23457, n = 3, l = [0.5, None]\n"
    figures.record("demo.a", {"x": 9.0}, ranks=1, command="cmd")  # fewer ranks: kept
    rec = figures.load(str(tmp_path))["demo.a"]
    assert rec["figures"] == {"x": 1.23457, "n": 3, "l": [0.5, None]} and rec["ranks"] == 2
    assert rec["source"].startswith("tests/test_figures.py::")  # the running test
    figures.record("demo.a", {"x": 2.0}, ranks=2, command="cmd")  # as many: replaced
    assert figures.load(str(tmp_path))["demo.a"]["figures"] == {"x": 2.0}
    with pytest.raises(ValueError, match="letters, digits"):
        figures.record("a b", {}, command="cmd")
    (tmp_path / "other.json").write_text(json.dumps({"name": "else"}))
    with pytest.raises(ValueError, match="other.json"):
        figures.load(str(tmp_path))


def test_render_rewrites_values_and_names_what_differs():
    records = {"s.d0.05": {"figures": {"front_m": 1.3912, "n": 116, "r": [0.9995, 0.9967]}}}
    text = ("front <!--{s.d0.05.front_m:.2f}-->1.2<!--/--> m, "
            "<!--{s.d0.05.n:,}-->116<!--/--> particles, <!--{s.d0.05.r[1]:.4f}-->x<!--/-->")
    new, differ = figures.render(text, records)
    assert new == ("front <!--{s.d0.05.front_m:.2f}-->1.39<!--/--> m, "
                   "<!--{s.d0.05.n:,}-->116<!--/--> particles, "
                   "<!--{s.d0.05.r[1]:.4f}-->0.9967<!--/-->")
    assert differ == [("s.d0.05.front_m", "1.2", "1.39"), ("s.d0.05.r[1]", "x", "0.9967")]
    assert figures.render(new, records)[1] == []
    with pytest.raises(KeyError, match="no figure 'missing'"):
        figures.render("<!--{s.d0.05.missing}-->1<!--/-->", records)
    with pytest.raises(KeyError, match="no figure record 'nope'"):
        figures.render("<!--{nope.x}-->1<!--/-->", records)
    shown = "`<!--{NAME.KEY:FORMAT}-->VALUE<!--/-->`"  # the syntax in a code span
    assert figures.render(shown, records) == (shown, [])
