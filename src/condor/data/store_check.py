"""The store's integrity: checks of what `condor.data.store` wrote, and its repair.

`check_metadata` compares every array's metadata with what the store was created with.
`scan_store` checks every chunk of every array that the flags say exists without
decompressing it (`frame_problem`: the file is there and holds one whole zstd frame of the
array's chunk length, then its checksum); it decodes only the flags, the layout and
n_replicas_ok, which say what should exist. `deep=True` decodes and checksums every chunk of
every array. `set_aside` moves damaged chunk files out of the store, so that the fast check
(and with it the workflow, condor.folder.store_gaps) sees them as lost; `restore_layout`
writes the layout again where it was damaged.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from condor.data.store import (COORDINATES, LAYOUT_VARIABLES, MOULD_ARRAYS, SAMPLE_ARRAYS, SPLITS,
                               expected_arrays, expected_fields, layout_values, ok_replicas,
                               open_group, quiet_zarr, sample_index, spec_of)

def check_metadata(path: str | Path) -> list[str]:
    """Problems with the arrays' metadata: the shape, chunks and data type zarr reads (the
    consolidated metadata) against what the attributes imply, and each array's own zarr.json
    against the consolidated copy (an edit to either is found)."""
    path = Path(path)
    group = open_group(path)
    consolidated = json.loads((path / "zarr.json").read_text()).get(
        "consolidated_metadata", {}).get("metadata", {})
    problems = []
    with quiet_zarr():
        for name, (shape, chunks, dtype, _) in expected_arrays(spec_of(group)).items():
            array = group[name]
            if array.shape != shape:
                problems.append(f"array {name}: shape {list(array.shape)}, expected {list(shape)}")
            if array.chunks != chunks:
                problems.append(f"array {name}: chunks {list(array.chunks)}, expected {list(chunks)}")
            if np.dtype(array.dtype) != np.dtype(dtype):
                problems.append(f"array {name}: data type {array.dtype}, expected {dtype}")
            try:
                own = json.loads((path / name / "zarr.json").read_text())
            except (OSError, ValueError) as err:
                problems.append(f"array {name}: unreadable zarr.json ({err})")
                continue
            if name in consolidated and _core(own) != _core(consolidated[name]):
                problems.append(f"array {name}: its zarr.json differs from the store's "
                                "consolidated metadata (edited?)")
    return problems


def _core(meta: dict) -> tuple:
    return tuple(json.dumps(meta.get(k), sort_keys=True)
                 for k in ("shape", "data_type", "chunk_grid", "codecs", "fill_value"))


# Chunks are checked without decompressing them: the file must hold exactly one whole zstd
# frame (its header and block headers give its length and the decoded length) and the
# checksum after it. A deleted, truncated or extended file, or one from another array, fails.
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
GRIDS = ("inputs", "lattice", "fields", "fields_mean", "fields_std")  # deep: finite, masks 0/1


@dataclass(frozen=True)
class Damage:
    """A chunk the store should hold whole but does not: the `array`, the chunk's `index`
    along its first axis, `where` in the dataset that is (a sample, a replicated mould, or ""
    for an array of one chunk), the `problem` and the chunk's `file`."""

    array: str
    index: int
    where: str
    problem: str
    file: Path

    def __str__(self) -> str:
        where = f"{self.where}, " if self.where else ""
        return f"{where}array {self.array}: chunk {self.file} {self.problem}"


@dataclass(frozen=True)
class StoreCheck:
    """What `scan_store` found: the per-sample table (see check_store), every damaged chunk
    of any array, and whether the dataset stage wrote the expected fields (`derived`; True
    for a store without replicated moulds)."""

    samples: pd.DataFrame
    damage: list[Damage]
    derived: bool


def chunk_file(path: str | Path, name: str, index: int, ndim: int) -> Path:
    """The file of chunk `index` (first axis) of array `name`: zarr v3 keys c/<i>/0/..."""
    return Path(path, name, "c", str(index), *["0"] * (ndim - 1))


def _chunk_format(array) -> tuple[bool, int, int]:
    """(zstd-compressed, checksum bytes after the data, decoded bytes) of `array`'s chunks."""
    names = [c["name"] for c in array.metadata.to_dict()["codecs"]]
    decoded = int(np.prod(array.chunks)) * np.dtype(array.dtype).itemsize
    return "zstd" in names, 4 * names.count("crc32c"), decoded


def frame_problem(file: Path, zstd: bool, trailer: int, decoded: int) -> str:
    """"" when `file` holds one whole zstd frame of `decoded` bytes then `trailer` checksum
    bytes (without zstd: `decoded` bytes then the trailer), else what is wrong. Reads a few
    header bytes per 128 KiB block, never decompresses."""
    try:
        fd = os.open(file, os.O_RDONLY)
    except FileNotFoundError:
        return "is missing"
    except OSError as err:
        return f"cannot be read ({err.strerror})"
    try:
        size = os.fstat(fd).st_size
        if not zstd:
            end = decoded + trailer
        else:
            head = os.pread(fd, 18, 0)
            if len(head) < 6 or head[:4] != _ZSTD_MAGIC:
                return f"is not a zstd frame ({size} bytes)"
            flags = head[4]
            single, fcs_flag = flags >> 5 & 1, flags >> 6
            pos = 5 + (1 - single) + (0, 1, 2, 4)[flags & 3]
            fcs = (single, 2, 4, 8)[fcs_flag]
            if fcs:
                if len(head) < pos + fcs:
                    return f"is truncated ({size} bytes)"
                content = int.from_bytes(head[pos:pos + fcs], "little") + (256 if fcs == 2 else 0)
                if content != decoded:
                    return f"decodes to {content} bytes, the array's chunks hold {decoded}"
            pos += fcs
            last = 0
            while not last:
                block = os.pread(fd, 3, pos)
                if len(block) < 3:
                    return f"is truncated ({size} bytes)"
                header = int.from_bytes(block, "little")
                last, kind = header & 1, header >> 1 & 3
                if kind == 3:
                    return "has a corrupt zstd block header"
                pos += 3 + (1 if kind == 1 else header >> 3)
            end = pos + 4 * (flags >> 2 & 1) + trailer
    finally:
        os.close(fd)
    if size != end:
        return f"holds {size} bytes, its headers say {end} (truncated or altered)"
    return ""


def scan_store(path: str | Path, deep: bool = False, split=None) -> StoreCheck:
    """Check every chunk of every array the store's flags say it holds (module docs).

    Fast (default): each such chunk file must exist and hold one whole frame of the right
    length (`frame_problem`); the small arrays that say what the store holds are decoded: the
    flags (inputs_ready, status), the layout (coordinates, each sample's mould, replica and
    split, compared with the attributes and, given the per-mould `split`, with it) and
    n_replicas_ok (compared with the statuses). `deep` also decodes every chunk of every array
    (checksums), checks that the grids that should be written are finite and the masks 0/1,
    and recomputes what is derived from the samples (`derived_problems`): a rewrite that kept
    its checksum valid is found too."""
    path = Path(path)
    group = open_group(path)
    spec = spec_of(group)
    n = spec.n_samples
    layout = layout_values(spec)
    replicated = layout.get("replicated", np.zeros(0, dtype="int64"))
    problems: dict[tuple[str, int], str] = {}
    expected: set[tuple[str, int]] = set()
    with quiet_zarr():
        arrays = {name: group[name] for name in (*layout, "split", *expected_arrays(spec))}
        formats = {name: _chunk_format(array) for name, array in arrays.items()}

        def check(name: str, index: int) -> bool:
            """Whether chunk `index` of `name`, which should exist, is whole."""
            expected.add((name, index))
            if (name, index) not in problems:
                problem = frame_problem(chunk_file(path, name, index, arrays[name].ndim),
                                        *formats[name])
                if problem:
                    problems[name, index] = problem
            return (name, index) not in problems

        def decoded(name: str, values: list) -> list:
            """`values` (from _read_each / _read_whole), noting a chunk that fails to decode."""
            for index, value in enumerate(values):
                if value is None:
                    problems.setdefault((name, index), frame_problem(
                        chunk_file(path, name, index, arrays[name].ndim), *formats[name])
                        or "fails its checksum or cannot be decoded")
            return values

        for name, want in layout.items():
            if name in COORDINATES:
                got = decoded(name, [_read_whole(arrays[name])])[0] if check(name, 0) else None
                if got is not None and not np.array_equal(got, want):
                    problems[name, 0] = (f"holds {list(got)}, the store's attributes say "
                                         f"{list(want)}")
                continue
            whole = [check(name, i) for i in range(n)]
            for i, value in enumerate(decoded(name, _read_each(arrays[name]))):
                if whole[i] and value is not None and value != want[i]:
                    problems[name, i] = f"holds {value!r}, the store's layout says {want[i]!r}"
        whole = [check("split", i) for i in range(n)]
        wanted = None if split is None else layout_values(spec, split)["split"]
        split = decoded("split", _read_each(arrays["split"]))
        for i, value in enumerate(split):
            if whole[i] and value is not None and value not in SPLITS:
                problems["split", i] = f"holds {value!r}, not one of {SPLITS}"
            elif whole[i] and value is not None and wanted is not None and value != wanted[i]:
                problems["split", i] = (f"holds {str(value)!r}, the data configuration's split "
                                        f"says {str(wanted[i])!r}")
        ready = decoded("inputs_ready", _read_each(arrays["inputs_ready"]))
        status = decoded("status", _read_each(arrays["status"]))
        for i in range(n):
            names = list(MOULD_ARRAYS) if ready[i] == 1 else []
            if status[i]:  # a failed simulation writes no fields
                names += [name for name in SAMPLE_ARRAYS if name != "fields" or status[i] == "ok"]
            for name in names:
                check(name, i)
        derived = not len(replicated)
        if len(replicated) and frame_problem(chunk_file(path, "n_replicas_ok", 0, 1),
                                             *formats["n_replicas_ok"]) != "is missing":
            derived = True  # the dataset stage wrote it: what it derives (write_expected's
            ok = np.asarray([value == "ok" for value in status])
            counts = [int(ok[layout["mould"] == mould].sum()) for mould in replicated]  # rule)
            got = (decoded("n_replicas_ok", [_read_whole(arrays["n_replicas_ok"])])[0]
                   if check("n_replicas_ok", 0) else None)
            if got is not None and list(got) != counts:
                problems["n_replicas_ok", 0] = f"holds {list(got)}, the statuses say {counts}"
            for k in np.flatnonzero(np.asarray(counts) >= 2):
                check("fields_mean", int(k))
                check("fields_std", int(k))
        if deep:
            for name, array in arrays.items():
                for index, values, err in _decoded(array):
                    if err is not None:
                        problems.setdefault((name, index), "fails its checksum" if "checksum"
                                            in str(err) else f"cannot be decoded ({err})"[:160])
                    elif (name, index) in expected and not _plausible(name, values):
                        problems.setdefault((name, index), "holds NaN, inf or a mask value "
                                            "other than 0/1")
            for key, problem in derived_problems(path, group, spec, status, ready,
                                                 problems).items():
                problems.setdefault(key, problem)
    mould_of, replica_of = layout["mould"], layout["replica"]
    order = {name: k for k, name in enumerate(arrays)}
    per_sample = {*MOULD_ARRAYS, *SAMPLE_ARRAYS, *LAYOUT_VARIABLES}
    damage = [Damage(name, index, _where(name, index, mould_of, replica_of, replicated), problem,
                     chunk_file(path, name, index, arrays[name].ndim))
              for (name, index), problem in sorted(problems.items(), key=lambda item: (
                  item[0][0] not in per_sample, item[0][1], order[item[0][0]]))]
    lost: dict[int, list[str]] = {}
    for d in damage:
        if d.array in per_sample:
            lost.setdefault(d.index, []).append(d.array)
    rows = []
    for i in range(n):
        if ready[i] is None or status[i] is None or i in lost:
            state = "corrupt"
        elif not ready[i]:
            state = "missing"
        else:
            state = {"": "pending", "ok": "ok"}.get(status[i], "failed")
        rows.append({"sample": i, "mould": int(mould_of[i]), "replica": int(replica_of[i]),
                     "split": split[i] or "", "inputs_ready": ready[i], "status": status[i],
                     "state": state, "lost": ",".join(lost.get(i, []))})
    return StoreCheck(pd.DataFrame(rows), damage, derived)


def derived_problems(path, group, spec, status, ready, known) -> dict[tuple[str, int], str]:
    """{(array, chunk): problem} of what the store derives from its samples, recomputed and
    compared (the deep check): each replicated mould's fields_mean and fields_std against the
    mean and spread of its ok replicas (condor.data.store.expected_fields, bit for bit), or
    NaN with fewer than two; every replica's copy of its mould's inputs, metadata and geometry
    (MOULD_ARRAYS) against replica 0's; a status that says a simulation failed against its
    fields (a failed simulation writes none: the status, written last, is the one to doubt).
    Chunks already `known` to be damaged are not read again."""
    problems: dict[tuple[str, int], str] = {}
    for i, value in enumerate(status):
        if value not in (None, "", "ok") and ("status", i) not in known and \
                chunk_file(path, "fields", i, 4).is_file():
            problems["status", i] = (f"says the simulation failed ({str(value)[:40]!r}), but the "
                                     "sample's fields are written")
    replicated = np.flatnonzero(np.asarray(spec.replica_counts) > 1)

    def read(name, index):
        if (name, index) in known:
            return None
        try:
            return np.asarray(group[name][index])
        except Exception:  # noqa: BLE001 - a damaged chunk: the decode loop names it
            return None

    with quiet_zarr():
        for k, mould in enumerate(replicated):
            samples = ok_replicas(spec, int(mould), status)
            if len(samples) >= 2:
                fields = [read("fields", s) for s in samples]
                if any(f is None for f in fields):
                    continue
                for name, want in zip(("fields_mean", "fields_std"), expected_fields(fields)):
                    got = read(name, k)
                    if got is not None and not np.array_equal(got, want, equal_nan=True):
                        what = "mean" if name == "fields_mean" else "spread"
                        problems[name, k] = (
                            f"differs from the {what} of the mould's {len(samples)} ok replicas, "
                            f"recomputed (largest difference {np.nanmax(np.abs(got - want)):.3g})")
            else:
                for name in ("fields_mean", "fields_std"):
                    got = read(name, k)
                    if got is not None and not np.isnan(got).all():
                        problems[name, k] = (f"holds values, but the mould has {len(samples)} ok "
                                             "replica(s), fewer than the 2 it takes")
        for mould in replicated:
            first, *others = [sample_index(spec.replica_counts, int(mould), r)
                              for r in range(spec.replica_counts[mould])]
            if ready[first] != 1:
                continue
            for name in MOULD_ARRAYS:
                want = read(name, first)
                for s in others:
                    got = read(name, s) if ready[s] == 1 else None
                    if want is not None and got is not None and \
                            not np.array_equal(got, want, equal_nan=got.dtype.kind == "f"):
                        problems[name, s] = (f"differs from replica 0's (sample {first}): every "
                                             f"replica holds its mould's {name}")
    return problems


def _where(name: str, index: int, mould_of, replica_of, replicated) -> str:
    if name in COORDINATES or name == "n_replicas_ok":
        return ""
    if name in ("fields_mean", "fields_std"):
        return f"mould {int(replicated[index])}"
    return f"sample {index} (mould {int(mould_of[index])} replica {int(replica_of[index])})"


def _plausible(name: str, values: np.ndarray) -> bool:
    """Whether a decoded chunk that should be written holds what it may (GRIDS)."""
    if name == "inputs":
        return bool(np.isin(values, (0, 1)).all())
    return name not in GRIDS or bool(np.isfinite(values).all())


def inputs_whole(path: str | Path, mould: int) -> bool:
    """Whether every replica of `mould` holds what the mould stage writes: its inputs_ready
    flag set and each chunk of MOULD_ARRAYS whole (frame_problem; nothing else decoded)."""
    group = open_group(path)
    counts = spec_of(group).replica_counts
    with quiet_zarr():
        arrays = {name: group[name] for name in MOULD_ARRAYS}
        for sample in (sample_index(counts, mould, r) for r in range(counts[mould])):
            try:
                if arrays["inputs_ready"][sample] != 1:
                    return False
            except Exception:  # a damaged flag (zarr raises many types)
                return False
            if any(frame_problem(chunk_file(path, name, sample, array.ndim), *_chunk_format(array))
                   for name, array in arrays.items()):
                return False
    return True


def check_store(path: str | Path, deep: bool = False) -> pd.DataFrame:
    """Per-sample state (scan_store): a DataFrame with columns sample, mould, replica, split,
    inputs_ready, status, `lost` (the arrays, comma-separated, with a damaged chunk of the
    sample, or "") and `state`: "missing" (no inputs yet), "pending" (inputs, no simulation),
    "ok", "failed" or "corrupt" (a chunk of the sample is absent, truncated, undecodable or
    holds what it must not). Without `deep`, no chunk but the flags' and the layout's is
    decompressed."""
    return scan_store(path, deep).samples


def set_aside(path: str | Path, damage: list[Damage]) -> Path | None:
    """Move each damaged chunk that is still a file out of the store, to the same place under
    `<store>.damaged/` (kept for inspection): the store then lacks it, which the fast check
    finds and the workflow's next run rebuilds. Returns that folder, None if nothing moved."""
    path = Path(path)
    aside = path.with_name(path.name + ".damaged")
    moved = None
    for d in damage:
        if d.file.is_file():
            target = aside / d.file.relative_to(path)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(d.file, target)
            moved = aside
    return moved


def restore_layout(path: str | Path, split=None) -> list[str]:
    """Rewrite what create_store wrote wherever it is lost, damaged or altered: the
    coordinates and each sample's mould, replica and, given the per-mould `split`, split.
    The bytes are create_store's. Returns "array[index]" of each chunk rewritten."""
    group = open_group(path, mode="r+")
    spec = spec_of(group)
    rewritten = []
    with quiet_zarr():
        for name, want in layout_values(spec, split).items():
            array = group[name]
            if name in COORDINATES:
                got = _read_whole(array)
                if got is None or not np.array_equal(got, want):
                    array[:] = want
                    rewritten.append(f"{name}[0]")
                continue
            for i, value in enumerate(_read_each(array)):
                if value is None or value != want[i]:
                    array[i] = want[i]
                    rewritten.append(f"{name}[{i}]")
    return rewritten


def _decoded(array, budget: int = 64 << 20):
    """(index, values, None) or (index, None, error) for each chunk along the first axis,
    decoded about `budget` bytes at a time; a block that fails is decoded chunk by chunk, so
    one bad chunk spoils only itself."""
    step = array.chunks[0]
    count = -(-array.shape[0] // step)
    block = max(1, budget // max(1, _chunk_format(array)[2]))
    for start in range(0, count, block):
        stop = min(count, start + block)
        try:
            values = array[start * step:stop * step]
        except Exception:  # zarr and its codecs raise many types for a damaged chunk
            for index in range(start, stop):
                try:
                    yield index, array[index * step:(index + 1) * step], None
                except Exception as err:
                    yield index, None, err
            continue
        for index in range(start, stop):
            yield index, values[(index - start) * step:(index - start + 1) * step], None


def _read_each(array) -> list:
    """Each entry of a one-entry-per-chunk array, None where its chunk cannot be decoded."""
    return [values[0] if values is not None else None for _, values, _ in _decoded(array)]


def _read_whole(array):
    """The values of a one-chunk array, None when its chunk cannot be decoded."""
    return next(_decoded(array))[1]
