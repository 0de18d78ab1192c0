"""The stage layer: each stage is a function of (config, explicit paths) that writes files.
The workflow's scripts and the `condor` CLI call these and nothing else.

`dataset` (store, moulds, simulation, fields), `surrogate` (train, evaluate), `studies`
(accuracy, ladder, convergence, stability); the report is `condor.report.page.condor_report`.
"""

from __future__ import annotations

import logging
from pathlib import Path

from condor.config import Config


def setup_logging(logfile: str | Path | None = None) -> None:
    """Log condor's progress to `logfile` (a job's log) and to stderr."""
    handlers = [logging.StreamHandler()]
    if logfile:
        Path(logfile).parent.mkdir(parents=True, exist_ok=True)
        handlers.append(logging.FileHandler(logfile, mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", handlers=handlers,
                        force=True)
    # ezdxf logs each DXF it writes (65 lines of "creating ACAD_... dictionary" a design job)
    logging.getLogger("ezdxf").setLevel(logging.WARNING)


def start_job(snakemake) -> Config:
    """A workflow job's Config (its surrogate section was checked when the workflow started,
    so torch is not imported here), with logging to the job's log file."""
    setup_logging(snakemake.log[0] if snakemake.log else None)
    return Config.from_dict(snakemake.config, check_surrogate=False)
