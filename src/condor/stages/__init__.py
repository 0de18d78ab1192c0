"""The stage layer: each stage is a function of (config, explicit paths) that writes files.
The workflow's scripts and the `condor` CLI call these and nothing else.

`dataset` (store, moulds, simulation, fields), `surrogate` (train, evaluate), `studies`
(accuracy, ladder, convergence, stability); the report is `condor.report.page.condor_report`.
"""

from __future__ import annotations

import logging
import sys
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
    so torch is not imported here), with logging to the job's log file, and a fault the user
    can mend said in one line (`job_faults`)."""
    setup_logging(snakemake.log[0] if snakemake.log else None)
    sys.excepthook = job_faults(snakemake.rule)
    return Config.from_dict(snakemake.config, check_surrogate=False)


def job_faults(rule: str):
    """An excepthook for a workflow job of `rule`: a fault the user can mend (a write that
    failed: disk full, a file-size limit, a read-only folder (condor.files); or an error of
    condor's own, whose message names the value and the way out) is one line on stderr,
    `condor: rule <rule>: <message>`, exit status 1; anything else (a bug) keeps its
    traceback."""
    from condor.files import fault_message, write_fault

    def hook(kind, err, trace):
        fault = write_fault(err)
        if fault is not None and not getattr(fault, "message", None):
            message = fault_message(fault.filename, fault)
        elif fault is not None or type(err).__module__.startswith("condor."):
            message = str(fault if fault is not None else err)
        else:
            return sys.__excepthook__(kind, err, trace)
        line = " ".join(part.strip() for part in message.splitlines() if part.strip())
        print(f"condor: rule {rule}: {line}", file=sys.stderr, flush=True)

    return hook
