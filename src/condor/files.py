"""Outputs written whole or not at all, and a failed write said in one line.

`atomic_path(path)` yields a temporary path beside `path` (the same folder, so that the final
rename is atomic; the same suffix, for writers that read it: numpy, matplotlib, zarr). When
the block ends without an error the temporary file or folder is renamed onto `path` (a folder
there is moved aside first and removed after); when it fails the temporary one is removed and
`path` is as it was. An OSError of a write that cannot succeed (`WRITE_FAULTS`: disk full, a
file-size limit, a read-only folder) becomes a `WriteError`, whose message is one line naming
`path` and the cause in words.
"""

from __future__ import annotations

import errno
import os
import shutil
from contextlib import contextmanager
from pathlib import Path

# errno -> the cause in words, for every fault that no retry of the same write mends
WRITE_FAULTS = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "the disk quota is exceeded",
    errno.EFBIG: "file too large (a file-size limit: see `ulimit -f`)",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied (a read-only folder?)",
    errno.EPERM: "operation not permitted (a read-only folder?)",
}


class WriteError(OSError):
    """A write that failed for a cause WRITE_FAULTS names; str() is one line: the path, the
    cause, and that nothing was left half-written."""

    def __init__(self, path, cause: int, message: str):
        super().__init__(cause, message, str(path))
        self.message = message

    def __str__(self) -> str:
        return self.message


def write_fault(err: BaseException) -> OSError | None:
    """The OSError of a WRITE_FAULTS cause in `err` or the exceptions it was raised from
    (a library may wrap it), else None."""
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        if isinstance(err, OSError) and err.errno in WRITE_FAULTS:
            return err
        err = err.__cause__ or err.__context__
    return None


def fault_message(path, err: OSError) -> str:
    """One line: `path` (None: a file the error does not name) cannot be written, and why
    (WRITE_FAULTS)."""
    cause = WRITE_FAULTS.get(err.errno) or err.strerror or str(err)
    return f"a write failed: {cause}" if path is None else f"cannot write {str(path)!r}: {cause}"


def temporary_path(path) -> Path:
    """A hidden name beside `path` for this process's temporary copy, with `path`'s suffix."""
    path = Path(path)
    stem = path.name[: len(path.name) - len(path.suffix)] if path.suffix else path.name
    return path.with_name(f".{stem}.part{os.getpid()}{path.suffix}")


def remove(path) -> None:
    """Remove the file, link or folder `path` if it is there (a failure to is ignored: a
    read-only folder, where nothing was created to remove)."""
    path = Path(path)
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass  # a read-only folder: nothing was created there to remove


@contextmanager
def atomic_path(path):
    """Write `path` whole or not at all (module docs): yields the temporary path to write."""
    path = Path(path)
    tmp = temporary_path(path)
    remove(tmp)  # left by a killed process whose PID this one reuses
    try:
        yield tmp
        if not (tmp.exists() or tmp.is_symlink()):
            raise FileNotFoundError(errno.ENOENT, f"the writer of {path} wrote nothing",
                                    str(tmp))
        if path.is_dir() and not path.is_symlink():
            old = path.with_name(f".{path.name}.old{os.getpid()}")
            remove(old)
            os.replace(path, old)
            os.replace(tmp, path)
            remove(old)
        else:
            os.replace(tmp, path)
    except BaseException as err:
        remove(tmp)
        failed = as_write_error(err, tmp, path)
        if failed is not None:
            raise failed from err
        raise


def as_write_error(err: BaseException, tmp, path) -> WriteError | None:
    """The WriteError to raise for `err`, raised while writing `path` as `tmp` (a temporary
    file or folder): it names `path` (or the file under it), not the temporary one. None when
    `err` is no write fault, or a WriteError of another file."""
    if not isinstance(err, Exception):
        return None
    fault = write_fault(err)
    if fault is None:
        return None
    tmp, path, where = Path(tmp), Path(path), path
    if isinstance(err, WriteError):
        failed = Path(err.filename)
        if failed != tmp and tmp not in failed.parents:
            return None  # another file's: it names it already
        where = path / failed.relative_to(tmp) if failed != tmp else path
    return WriteError(where, fault.errno, fault_message(where, fault) + "; nothing was written")


def write_bytes(path, data) -> Path:
    """Write `data` (bytes or a buffer) to `path` whole or not at all."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
    return Path(path)


def write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write `text` to `path` whole or not at all."""
    return write_bytes(path, text.encode(encoding))
