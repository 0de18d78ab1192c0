"""Progress you can watch: a tqdm bar with an ETA on a terminal, nothing on a log file.

Long steps (simulation batches, training epochs, the design search, the studies) wrap their
loop in `progress(...)`. On a terminal it draws a bar with rate and ETA on stderr; when stderr
is not a terminal (a Snakemake job's log, CI) the bar is off, and the stages' own log lines
(one per mould, one per epoch) are the record.
"""

from __future__ import annotations

import sys

from tqdm.auto import tqdm


def on_terminal() -> bool:
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def progress(iterable=None, total: int | None = None, desc: str = "", unit: str = "it"):
    """tqdm over `iterable` (or a manual bar of `total`), disabled off a terminal."""
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=not on_terminal(),
                dynamic_ncols=True, leave=False)
