"""Progress bars: an ETA on a terminal, nothing in a log file."""

import io
import sys

from condor.progress import progress


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_bar_on_a_terminal_and_silence_in_a_log(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert list(progress(range(5), desc="simulate", unit="sim")) == list(range(5))
    shown = terminal.getvalue()
    assert "simulate" in shown and "/5 [" in shown  # a bar with its count and rate
    log = io.StringIO()  # a Snakemake job's log: not a terminal
    monkeypatch.setattr(sys, "stderr", log)
    assert list(progress(range(5), desc="simulate")) == list(range(5))
    assert log.getvalue() == ""
