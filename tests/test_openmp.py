"""condor.openmp: how OpenMP's threads wait, from a look at how busy the machine is."""

from __future__ import annotations

import sys

import pytest

from condor import openmp

STAT = "cpu  {user} 0 {system} {idle} {iowait} 0 0 {steal} 0 0\\ncpu0 1 2 3 4 5 6 7 8 9 10\\n"


def stat(user=0, system=0, idle=0, iowait=0, steal=0) -> str:
    return STAT.format(user=user, system=system, idle=idle, iowait=iowait, steal=steal)


def test_busy_ticks_are_every_tick_but_idle_and_iowait():
    text = stat(user=10, system=5, idle=100, iowait=7, steal=3)
    assert openmp.cpu_times(text) == (10 + 5 + 3, 10 + 5 + 100 + 7 + 3)
    with pytest.raises(ValueError, match="cpu"):
        openmp.cpu_times("intr 1 2 3\\n")


def test_busy_cores_is_the_busy_share_of_the_ticks_times_the_cores(tmp_path, monkeypatch):
    """Two reads of a file that changes between them: 30 of 100 ticks busy on 4 cores is 1.2
    cores (the sleep between the reads replaced by the change)."""
    path = tmp_path / "stat"
    path.write_text(stat(user=100, idle=1000))
    monkeypatch.setattr(openmp.os, "cpu_count", lambda: 4)
    monkeypatch.setattr(openmp.time, "sleep",
                        lambda s: path.write_text(stat(user=120, system=10, idle=1070)))
    assert openmp.busy_cores(0.05, str(path)) == pytest.approx(30 / 100 * 4)
    assert openmp.busy_cores(0.05, str(tmp_path / "missing")) is None


def test_an_idle_machine_spins_briefly_and_a_busy_or_unknown_one_sleeps():
    assert openmp.wait_settings(0.0) == {"OMP_WAIT_POLICY": None,
                                         "GOMP_SPINCOUNT": str(openmp.SPIN_COUNT),
                                         openmp.MARK: "spin"}
    for busy in (openmp.IDLE_CORES, 1.0, None):
        assert openmp.wait_settings(busy) == {"OMP_WAIT_POLICY": "PASSIVE",
                                              "GOMP_SPINCOUNT": None, openmp.MARK: "sleep"}


def test_the_users_setting_is_kept_and_condors_own_is_looked_at_again(monkeypatch):
    monkeypatch.delitem(sys.modules, "torch", raising=False)

    def never():
        raise AssertionError("looked at the machine although the user chose")
    users = {"GOMP_SPINCOUNT": "5"}
    assert openmp.choose_wait(users, look=never) == "user" and users == {"GOMP_SPINCOUNT": "5"}
    # a parent's choice (marked) is made again for this process: busy now, so it sleeps
    inherited = {"GOMP_SPINCOUNT": str(openmp.SPIN_COUNT), openmp.MARK: "spin", "PATH": "/bin"}
    assert openmp.choose_wait(inherited, look=lambda: 1.0) == "sleep"
    assert inherited == {"OMP_WAIT_POLICY": "PASSIVE", openmp.MARK: "sleep", "PATH": "/bin"}
    assert openmp.choose_wait(inherited, look=lambda: 0.1) == "spin"
    assert inherited == {"GOMP_SPINCOUNT": str(openmp.SPIN_COUNT), openmp.MARK: "spin",
                         "PATH": "/bin"}


def test_nothing_changes_once_the_runtime_has_loaded(monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", object())
    environ = {}
    assert openmp.choose_wait(environ, look=lambda: 0.0) == "loaded" and environ == {}
