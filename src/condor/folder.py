"""The results folder: built for one data configuration, used by one run at a time, repaired
where its store lost what its flag files claim.

- `check_folder(config)`: a folder already holding data for another data configuration
  (`Config.data_config()`: scene, seed, moulds, batching, split, solver, replicas) stops the
  workflow before any job runs, naming each differing key, the folder and what to do. Three
  records say what a folder was built for: the store's attributes, its manifest
  (`dataset.json`) and the folder's own record (`FOLDER_RECORD`, written with the store, so
  that a deleted store and manifest leave one behind); each that is there must match. A
  folder holding data (moulds, simulations, fields) with none of them is refused too: its
  data cannot be checked. Nothing is mixed into a store and nothing is silently left stale.
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
from condor.files import WRITE_FAULTS, write_fault
from condor.data.store import MOULD_ARRAYS, SAMPLE_ARRAYS, StoreError, open_group
from condor.data.store_check import scan_store

LOCK_NAME = ".condor.lock"
FOLDER_RECORD = ".condor.folder.json"  # the data configuration the folder holds
MANIFEST = "dataset.json"  # init_store's output: the store exists, and for which data
DATA_FOLDERS = ("moulds", "sims", "fields")  # per-batch files the data of the folder is made of


class FolderError(RuntimeError):
    """A results folder that cannot be used as asked; the message says why and what to do."""


def unwritable(results: str | Path, err: OSError) -> FolderError:
    """The FolderError of a results folder that a write fault (condor.files) stops: one line,
    the folder, the file and the cause."""
    cause = WRITE_FAULTS.get(err.errno) or err.strerror or str(err)
    return FolderError(f"results folder {str(results)!r} cannot be written ({cause}: "
                       f"{err.filename}); make it writable or point `results` at another "
                       "folder (e.g. --config results=results_new)")


def store_path(results: str | Path) -> Path:
    """Where a results folder keeps its dataset store."""
    return Path(results) / "dataset.zarr"


def folder_record(results: str | Path) -> Path:
    """Where a results folder records the data configuration it holds (FOLDER_RECORD)."""
    return Path(results) / FOLDER_RECORD


def data_files(results: str | Path) -> list[str]:
    """The folders of `results` (DATA_FOLDERS) that hold files of its data, by name."""
    return [name for name in DATA_FOLDERS
            if (Path(results) / name).is_dir() and any((Path(results) / name).iterdir())]


def records(results: str | Path, store: str | Path | None = None) -> list[tuple[Path, dict]]:
    """[(file, the data configuration it records)] of each record of the folder that is there:
    the store's attributes, its manifest, the folder's record (module docs). FolderError when
    one cannot be read."""
    results = Path(results)
    store = store_path(results) if store is None else Path(store)
    found = []
    if store.exists():
        try:
            found.append((store, open_group(store).attrs.get("data_config") or {}))
        except StoreError as err:
            raise FolderError(f"{err}. Move or delete {store} (its samples cannot be reused) "
                              "or point `results` at a new folder") from err
    for path in (results / MANIFEST, folder_record(results)):
        if path.is_file():
            try:
                recorded = json.loads(path.read_text()).get("data_config")
            except (OSError, ValueError, AttributeError) as err:
                raise FolderError(f"{path} cannot be read ({err}): it records the data "
                                  f"configuration of {results}; delete {results} to rebuild it, "
                                  "or point `results` at a new folder") from None
            if recorded is not None:
                found.append((path, recorded))
    return found


def check_folder(config: Config, store: str | Path | None = None) -> None:
    """FolderError when `config.results` is not a usable folder for `config`: it is a file, a
    record of it says it holds data of another data configuration, or it holds data and no
    record of what for (module docs)."""
    results = Path(config.results)
    if results.exists() and not results.is_dir():
        raise FolderError(f"results folder {str(results)!r} is a file; point `results` at a "
                          "folder (e.g. --config results=results/run2)")
    wanted = json.loads(json.dumps(config.data_config()))
    found = records(results, store)
    if not found:
        held = data_files(results)
        if held:
            raise FolderError(
                f"results folder {str(results)!r} holds data ({', '.join(f'{n}/' for n in held)}) "
                f"but no record of the configuration it was built for (its store, {MANIFEST} and "
                f"{FOLDER_RECORD} are gone), so it cannot be checked against this one. Nothing "
                f"was run. Delete {', '.join(str(results / n) for n in held)} to rebuild the "
                f"data, or use a new folder (e.g. --config results={results}_new)")
        return
    for where, built_for in found:
        if built_for == wanted:
            continue
        diffs = [f"{key}: folder has {built_for.get(key)!r}, config asks {value!r}"
                 for key, value in wanted.items() if built_for.get(key) != value] or \
            [f"{key}: folder has {value!r}, this code has no such key"
             for key, value in built_for.items() if key not in wanted]
        raise FolderError(
            f"results folder {str(results)!r} holds a dataset built for another configuration "
            f"({'; '.join(diffs)}; recorded in {where}). Nothing was run. Use a new folder for "
            f"this configuration (e.g. --config results="
            f"{results}_{diffs[0].split(':')[0] if diffs else 'new'}), or delete {results} to "
            "rebuild it, or go back to the folder's settings")


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
        except OSError as err:
            if write_fault(err) is None:
                raise
            raise unwritable(results, err) from None
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

def store_gaps(store: str | Path, split=None) -> dict[str, set]:
    """What the store lacks, by the step that writes it again (condor.data.store_check.scan_store: chunk
    files listed and their headers read; only the flags and the layout are decompressed):
    {"inputs": moulds with a replica whose inputs are not ready or with a damaged chunk of an
    array the mould stage writes, "fields": those and the moulds with a replica not yet
    simulated or with a damaged chunk of an array the fields stage writes, "dataset": the
    arrays the dataset step writes again (the layout, the coordinates and the expected
    fields) that are damaged or not yet derived}. `split`: the per-mould split the config
    gives (a sample holding another is damaged layout)."""
    check = scan_store(store, split=split)
    table = check.samples
    lost = table["lost"].str.split(",").apply(set)
    no_inputs = table["inputs_ready"].ne(1) | lost.apply(lambda a: bool(a & set(MOULD_ARRAYS)))
    no_fields = (no_inputs | table["status"].isna() | table["status"].eq("")
                 | lost.apply(lambda a: bool(a & set(SAMPLE_ARRAYS))))
    dataset = {d.array for d in check.damage if d.array not in (*MOULD_ARRAYS, *SAMPLE_ARRAYS)}
    return {"inputs": set(table.loc[no_inputs, "mould"].astype(int)),
            "fields": set(table.loc[no_fields, "mould"].astype(int)),
            "dataset": dataset | (set() if check.derived else {"n_replicas_ok"})}
