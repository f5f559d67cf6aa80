"""The benchmark jobs read their workers' output robustly (terminal codes from Open MPI's
pseudo-terminal, a missing line)."""
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "jobs"))
from benchlib import worker_line  # noqa: E402


def test_worker_line_survives_terminal_codes():
    out = ("numba warming up\r\n\x1b[0mPARSPH 0.0123 8000 53.2 1800\r\n"
           "\x1b]0;title\x07\x1b[?25h\n")
    assert worker_line(out, "PARSPH ", "worker").split() == ["0.0123", "8000", "53.2", "1800"]
    # the last such line wins, and a tag in the middle of a line is found
    out = "PARSPH 1 2 3 4\n[1,0]<stdout>: \x1b[1mPARSPH 5 6 7 8\x1b[0m\n"
    assert worker_line(out, "PARSPH ", "worker") == "5 6 7 8"


def test_worker_line_names_the_worker_and_shows_its_output():
    with pytest.raises(SystemExit) as err:
        worker_line("Traceback (most recent call last):\n  boom\n", "PARSPH ", "parsph worker")
    text = str(err.value)
    assert "parsph worker" in text and "'PARSPH'" in text and "boom" in text
