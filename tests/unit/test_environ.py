"""vcirun.core.environ.getenv reads the mapping os.environ keeps, as os.environ.get does; the key of a
kept plan follows the variables that choose its module."""
from __future__ import annotations

import os

import pytest

from vcirun.core.environ import getenv


@pytest.mark.parametrize("value", ["", "1", "specialized", " padded ", "caf\u00e9", "a=b;c", "\udcff"])
def test_a_set_variable_reads_as_os_environ_get(monkeypatch, value):
    monkeypatch.setenv("VCIRUN_TEST_ENV", value)
    assert getenv("VCIRUN_TEST_ENV") == os.environ.get("VCIRUN_TEST_ENV") == value
    assert getenv("VCIRUN_TEST_ENV", "default") == value


def test_an_unset_variable_gives_the_default_and_follows_later_changes(monkeypatch):
    monkeypatch.delenv("VCIRUN_TEST_ENV", raising=False)
    assert getenv("VCIRUN_TEST_ENV") is None and getenv("VCIRUN_TEST_ENV", "x") == "x"
    os.environ["VCIRUN_TEST_ENV"] = "later"
    try:
        assert getenv("VCIRUN_TEST_ENV", "x") == "later"
    finally:
        del os.environ["VCIRUN_TEST_ENV"]
    assert getenv("VCIRUN_TEST_ENV", "x") == "x"


def test_every_variable_of_this_process():
    for k, v in os.environ.items():
        assert getenv(k) == v


@pytest.mark.parametrize("name", ["VCIRUN_BUILD", "NUMBA_DISABLE_JIT", "VCIRUN_CORE_NDOF", "VCIRUN_KERNEL_PATH"])
def test_a_kept_plan_is_not_reused_under_another_build_setting(monkeypatch, name):
    from vcirun.run.plan import _key

    args = ("cart_pendulum", "CVA", 1e-2, 1.0, 0.0, None, True, True, {}, "auto")
    monkeypatch.delenv(name, raising=False)
    unset = _key(*args)
    monkeypatch.setenv(name, "")
    empty = _key(*args)
    monkeypatch.setenv(name, "specialized")
    assert len({unset, empty, _key(*args)}) == 3
