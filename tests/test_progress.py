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


def test_a_jobs_log_holds_condors_lines_not_ezdxfs(tmp_path):
    import logging

    import ezdxf

    from condor.stages import setup_logging
    log = tmp_path / "job.log"
    try:
        setup_logging(log)
        ezdxf.new().saveas(tmp_path / "x.dxf")  # ezdxf logs "creating ACAD_..." at INFO
        logging.getLogger("condor").info("phase 1/4")
    finally:
        logging.getLogger().handlers.clear()
    text = log.read_text()
    assert "phase 1/4" in text and "ACAD" not in text
