"""The results folder: built for one data configuration, used by one run at a time, repaired
where its store lost what its flag files claim.

- `check_folder(config)`: a folder already holding data (its store) for another data
  configuration (`Config.data_config()`: scene, seed, moulds, batching, split, solver,
  replicas) stops the workflow before any job runs, naming each differing key, the folder
  and what to do. Nothing is mixed into a store and nothing is silently left stale.
- `RunLock`: `<results>/.condor.lock` holds the PID, the process start time and the host of
  the run that holds the folder. A second run stops at once with a message; a lock whose
  process is gone (a SIGKILL, a power cut) or whose PID now belongs to another process
  (another start time) is stale and taken over.
- `store_gaps(store)`: the moulds whose inputs or samples are not whole in the store, and the
  store-wide arrays that are not, so that the workflow reruns exactly the batches (and the
  dataset step) that write them again (a deleted or truncated chunk, a killed write).
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

from condor.config import Config
from condor.data.store import MOULD_ARRAYS, SAMPLE_ARRAYS, StoreError, open_group
from condor.data.store_check import scan_store

LOCK_NAME = ".condor.lock"


class FolderError(RuntimeError):
    """A results folder that cannot be used as asked; the message says why and what to do."""


def store_path(results: str | Path) -> Path:
    """Where a results folder keeps its dataset store."""
    return Path(results) / "dataset.zarr"


def check_folder(config: Config, store: str | Path | None = None) -> None:
    """FolderError when `config.results` is not a usable folder for `config`: it is a file, or
    its store was built for another data configuration."""
    results = Path(config.results)
    if results.exists() and not results.is_dir():
        raise FolderError(f"results folder {str(results)!r} is a file; point `results` at a "
                          "folder (e.g. --config results=results/run2)")
    store = store_path(results) if store is None else Path(store)
    if not store.exists():
        return
    try:
        built_for = open_group(store).attrs.get("data_config")
    except StoreError as err:
        raise FolderError(f"{err}. Move or delete {store} (its samples cannot be reused) or "
                          "point `results` at a new folder") from err
    wanted = json.loads(json.dumps(config.data_config()))
    if built_for == wanted:
        return
    built_for = built_for or {}
    diffs = [f"{key}: folder has {built_for.get(key)!r}, config asks {value!r}"
             for key, value in wanted.items() if built_for.get(key) != value]
    raise FolderError(
        f"results folder {str(results)!r} holds a dataset built for another configuration "
        f"({'; '.join(diffs)}). Nothing was run. Use a new folder for this configuration "
        f"(e.g. --config results={results}_{diffs[0].split(':')[0] if diffs else 'new'}), "
        f"or delete {results} to rebuild it, or go back to the folder's settings")


# --- one run at a time -----------------------------------------------------------------------

def _process_start(pid: int) -> str | None:
    """The start time of process `pid` (clock ticks since boot), None when it does not exist."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except PermissionError:
            return "unknown"
        return "unknown"  # no /proc (not Linux): alive, start time unknown
    return stat.rsplit(")", 1)[1].split()[19]


class RunLock:
    """An exclusive, SIGKILL-proof lock on a results folder (see the module docstring)."""

    def __init__(self, results: str | Path, pid: int | None = None):
        self.path = Path(results) / LOCK_NAME
        self.pid = os.getpid() if pid is None else int(pid)
        self.me = {"pid": self.pid, "start": _process_start(self.pid),
                   "host": socket.gethostname()}

    def holder(self) -> dict | None:
        """The live run that holds the lock, or None (no lock, or a stale one)."""
        try:
            held = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None
        if held.get("host") != self.me["host"]:
            return held  # another machine's run: its liveness cannot be checked from here
        start = _process_start(int(held.get("pid", -1)))
        if start is None or (start != "unknown" and start != held.get("start")):
            return None
        return held

    def acquire(self) -> None:
        """Take the lock; FolderError naming the holder when a live run has it, or the folder
        when it cannot be written."""
        results = self.path.parent
        try:
            self._acquire()
        except PermissionError as err:
            raise FolderError(f"results folder {str(results)!r} cannot be written "
                              f"(permission denied: {err.filename}); is it read-only? Make it "
                              "writable or point `results` at another folder") from None
        # its stage folders too (figures/, models/, ...): else a job fails with a traceback
        read_only = [entry.path for entry in os.scandir(results)
                     if entry.is_dir(follow_symlinks=False) and not os.access(entry.path, os.W_OK)]
        if read_only:
            self.release()
            raise FolderError(f"results folder {str(results)!r} holds folders that cannot be "
                              f"written: {', '.join(sorted(read_only))}; is it read-only? Make "
                              "them writable or point `results` at another folder")

    def _acquire(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                held = self.holder()
                if held is not None and held.get("pid") != self.pid:
                    raise FolderError(
                        f"results folder {str(self.path.parent)!r} is in use by another run "
                        f"(PID {held.get('pid')} on {held.get('host')}); wait for it to finish, "
                        f"or, if it is dead, delete {self.path}") from None
                self.path.unlink(missing_ok=True)  # stale, or ours already
                continue
            with os.fdopen(fd, "w") as fh:
                json.dump(self.me, fh)
            return
        raise FolderError(f"could not take the lock {self.path}")

    def release(self) -> None:
        """Drop the lock if this process holds it."""
        try:
            held = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return
        if held.get("pid") == self.pid and held.get("host") == self.me["host"]:
            self.path.unlink(missing_ok=True)


# --- repairs -----------------------------------------------------------------------------------

def store_gaps(store: str | Path) -> dict[str, set]:
    """What the store lacks, by the step that writes it again (condor.data.store_check.scan_store: chunk
    files listed and their headers read; only the flags and the layout are decompressed):
    {"inputs": moulds with a replica whose inputs are not ready or with a damaged chunk of an
    array the mould stage writes, "fields": those and the moulds with a replica not yet
    simulated or with a damaged chunk of an array the fields stage writes, "dataset": the
    arrays the dataset step writes again (the layout, the coordinates and the expected
    fields) that are damaged or not yet derived}."""
    check = scan_store(store)
    table = check.samples
    lost = table["lost"].str.split(",").apply(set)
    no_inputs = table["inputs_ready"].ne(1) | lost.apply(lambda a: bool(a & set(MOULD_ARRAYS)))
    no_fields = (no_inputs | table["status"].isna() | table["status"].eq("")
                 | lost.apply(lambda a: bool(a & set(SAMPLE_ARRAYS))))
    dataset = {d.array for d in check.damage if d.array not in (*MOULD_ARRAYS, *SAMPLE_ARRAYS)}
    return {"inputs": set(table.loc[no_inputs, "mould"].astype(int)),
            "fields": set(table.loc[no_fields, "mould"].astype(int)),
            "dataset": dataset | (set() if check.derived else {"n_replicas_ok"})}
