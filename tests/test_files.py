"""Outputs written whole or not at all, and a failed write said in one line (condor.files)."""

import errno
import resource
import subprocess
import sys

import numpy as np
import pytest

from condor.files import WriteError, atomic_path, temporary_path, write_bytes, write_text


def listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_file_appears_whole_at_the_end_with_its_suffix_kept(tmp_path):
    out = tmp_path / "f.npy"
    with atomic_path(out) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".npy" and tmp.name.startswith(".")
        np.save(tmp, np.arange(3))  # numpy would append .npy to any other name
        assert not out.exists()
    np.testing.assert_array_equal(np.load(out), np.arange(3))
    assert listing(tmp_path) == ["f.npy"]


def test_a_failure_leaves_the_old_output_and_no_temporary_file(tmp_path):
    out = write_text(tmp_path / "a.json", "old")
    with pytest.raises(KeyError):
        with atomic_path(out) as tmp:
            tmp.write_text("half")
            raise KeyError("the writer failed")
    assert out.read_text() == "old" and listing(tmp_path) == ["a.json"]


@pytest.mark.parametrize("code, cause", [(errno.ENOSPC, "disk is full"),
                                         (errno.EFBIG, "ulimit -f"),
                                         (errno.EROFS, "read-only file system"),
                                         (errno.EACCES, "permission denied")])
def test_a_write_fault_is_one_line_naming_the_output_and_the_cause(tmp_path, code, cause):
    with pytest.raises(WriteError) as info:
        with atomic_path(tmp_path / "out.png") as tmp:
            tmp.write_bytes(b"part")
            raise OSError(code, "the system's words")  # as write() raises it: no file name
    message = str(info.value)
    assert "\n" not in message and "out.png" in message and cause in message
    assert "nothing was written" in message and info.value.errno == code
    assert listing(tmp_path) == []


def test_a_fault_inside_a_library_error_is_found(tmp_path):
    with pytest.raises(WriteError, match="cannot write .*x.bin.* disk is full"):
        with atomic_path(tmp_path / "x.bin"):
            try:
                raise OSError(errno.ENOSPC, "No space left on device")
            except OSError as err:
                raise RuntimeError("a library's own words") from err


def test_a_folder_replaces_a_folder_whole(tmp_path):
    out = tmp_path / "p.zarr"
    (out / "old").mkdir(parents=True)
    with atomic_path(out) as tmp:
        (tmp / "new").mkdir(parents=True)
    assert listing(out) == ["new"] and listing(tmp_path) == ["p.zarr"]


def test_a_nested_writer_is_named_by_the_outer_output(tmp_path):
    """A writer that is itself atomic (plots.save, save_json) writing the temporary path: the
    message names the output, not the temporary name."""
    out = tmp_path / "m.json"
    with pytest.raises(WriteError) as info:
        with atomic_path(out) as tmp:
            with atomic_path(tmp) as inner:
                inner.write_text("x")
                raise OSError(errno.EFBIG, "File too large")
    assert str(out) in str(info.value) and temporary_path(out).name not in str(info.value)


def test_a_real_file_size_limit_leaves_nothing(tmp_path):
    """Under `ulimit -f` (RLIMIT_FSIZE) the write fails with EFBIG part-way: nothing stays."""
    code = ("import sys; from condor.files import write_bytes\n"
            "try:\n    write_bytes(sys.argv[1], bytes(100_000))\n"
            "except OSError as err:\n    print(err)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "big.bin")],
                          capture_output=True, text=True,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE,
                                                                (10_240, 10_240)))
    assert "big.bin" in proc.stdout and "file too large" in proc.stdout, proc.stdout + proc.stderr
    assert listing(tmp_path) == []
    write_bytes(tmp_path / "big.bin", bytes(100_000))  # without the limit: whole
    assert (tmp_path / "big.bin").stat().st_size == 100_000
