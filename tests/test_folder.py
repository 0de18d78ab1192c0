"""The results folder (condor.folder): one data configuration per folder, one run at a time,
and the gaps a repair must fill."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import shapely
import pytest

from condor.config import Config
from condor.folder import FolderError, RunLock, check_folder, store_gaps, store_path
from condor.data.store import (create_store, sample_index, write_expected, write_inputs,
                               write_sample)

BASE = {"scene": "tiny", "seed": 1, "n_moulds": 6, "split": {"test": 2},
        "simulation": {"replicas": {"test": 4}}}


def config_in(tmp_path, **changes):
    return Config.from_dict({**BASE, "results": str(tmp_path / "results"), **changes})


def test_a_folder_built_for_other_data_stops_and_names_each_key(tmp_path):
    config = config_in(tmp_path)
    check_folder(config)  # no store yet: fine
    create_store(store_path(config.results), config.store_spec())
    check_folder(config)  # the same data configuration: fine
    for change, key in (({"seed": 7}, "seed"), ({"n_moulds": 8}, "n_moulds"),
                        ({"simulation": {"solver": "anneal"}}, "solver"),
                        ({"batch_size": 3}, "batch_size"), ({"scene": "default"}, "scene"),
                        ({"simulation": {"replicas": {"test": 5}}}, "replicas")):
        with pytest.raises(FolderError, match=key) as info:
            check_folder(config_in(tmp_path, **change))
        assert "Nothing was run" in str(info.value) and str(config.results) in str(info.value)
    # Settings that do not define the data are no reason to stop.
    check_folder(config_in(tmp_path, report={"moulds": 2}))


def test_a_results_path_that_is_a_file_is_named(tmp_path):
    (tmp_path / "results").write_text("not a folder")
    with pytest.raises(FolderError, match="is a file"):
        check_folder(config_in(tmp_path))


def _other_process():
    """A live process that is not this one (a `sleep`)."""
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])


def test_lock_refuses_a_live_run_and_takes_over_a_dead_one(tmp_path):
    other = _other_process()
    try:
        RunLock(tmp_path, pid=other.pid).acquire()
        mine = RunLock(tmp_path)
        with pytest.raises(FolderError, match=f"PID {other.pid}"):
            mine.acquire()
    finally:
        other.kill()
        other.wait()
    mine.acquire()  # the holder died (as after a SIGKILL): the stale lock is taken over
    assert json.loads((tmp_path / ".condor.lock").read_text())["pid"] == os.getpid()
    mine.release()
    assert not (tmp_path / ".condor.lock").exists()


def test_a_reused_pid_does_not_hold_the_lock(tmp_path):
    lock = RunLock(tmp_path)
    held = dict(lock.me, start="1")  # our PID, another start time: a dead run's PID reused
    (tmp_path / ".condor.lock").write_text(json.dumps({**held, "pid": os.getppid()}))
    assert RunLock(tmp_path).holder() is None
    lock.acquire()
    lock.release()


def simulated_store(tmp_path):
    """The config's store with every sample simulated (the expected fields not derived)."""
    config = config_in(tmp_path)
    store = store_path(config.results)
    create_store(store, config.store_spec())
    replicas = config.replicas()
    meta = {"seed": 1, "symmetry": "x", "order": 1, "removal": "none", "n_tethers": 2}
    sim = {"sim_seed": 0, "n_cells": 10, "energy": 1.0, "max_force": 0.0, "solver": "hybrid",
           "solver_seconds": 1.0, "hardware": "test"}
    for mould in range(config.n_moulds):
        write_inputs(store, mould, np.ones((2, 32, 32), np.uint8), meta, lattice=np.zeros((2, 32, 32), np.float32),
                     polygon=shapely.box(1, 1, 7, 7), tethers=np.full((2, 3), 2.0))
        for r in range(replicas[mould]):
            write_sample(store, sample_index(replicas, mould, r),
                         np.ones((8, 32, 32), np.float32), sim, "ok")
    return config, store


def test_store_gaps_name_the_moulds_that_lost_samples(tmp_path):
    config, store = simulated_store(tmp_path)
    replicas = config.replicas()
    # the expected fields are not derived yet: the dataset step writes them
    assert store_gaps(store) == {"inputs": set(), "fields": set(), "dataset": {"n_replicas_ok"}}
    write_expected(store)
    assert store_gaps(store) == {"inputs": set(), "fields": set(), "dataset": set()}
    test_mould = config.test_moulds()[0]
    shutil.rmtree(store / "fields" / "c" / str(sample_index(replicas, test_mould, 1)))
    shutil.rmtree(store / "inputs" / "c" / "0")
    assert store_gaps(store) == {"inputs": {0}, "fields": {0, test_mould}, "dataset": set()}
    shutil.rmtree(store / "lattice" / "c" / "1")  # the lattice channels are inputs too
    assert store_gaps(store) == {"inputs": {0, 1}, "fields": {0, 1, test_mould}, "dataset": set()}


def test_store_gaps_send_each_damaged_chunk_to_the_step_that_writes_it(tmp_path):
    """A chunk file (not its folder) deleted, truncated or flipped, of any array: its mould
    is named (inputs, fields), or the array the dataset step writes again."""
    config, store = simulated_store(tmp_path)
    write_expected(store)
    test_mould = config.test_moulds()[0]
    flipped = store / "inputs_ready" / "c" / "1"  # a flag that no longer decodes
    data = bytearray(flipped.read_bytes())
    data[-1] ^= 0x01
    flipped.write_bytes(bytes(data))
    (store / "inputs" / "c" / "2" / "0" / "0" / "0").unlink()
    replica = sample_index(config.replicas(), test_mould, 1)
    truncated = store / "fields" / "c" / str(replica) / "0" / "0" / "0"
    truncated.write_bytes(truncated.read_bytes()[:-9])
    (store / "energy" / "c" / "3").unlink()
    (store / "split" / "c" / "4").unlink()
    (store / "fields_mean" / "c" / "0" / "0" / "0" / "0").unlink()
    assert store_gaps(store) == {"inputs": {1, 2}, "fields": {1, 2, 3, test_mould},
                                 "dataset": {"split", "fields_mean"}}
