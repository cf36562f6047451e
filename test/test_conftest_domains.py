"""The test suite's ROS domain blocks (test/conftest.py): pytest-xdist workers never share an id."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

CONFTEST = Path(__file__).parent / 'conftest.py'


def _block(monkeypatch: pytest.MonkeyPatch, **env: str) -> list[int]:
    for key in ('CVJ_TEST_DOMAINS', 'CVJ_TEST_DOMAIN_SPAN', 'CVJ_TEST_FRESH_DOMAIN', 'ROS_DOMAIN_ID',
                'PYTEST_XDIST_WORKER', 'PYTEST_XDIST_WORKER_COUNT', 'PYTEST_XDIST_TESTRUNUID'):
        monkeypatch.delenv(key, raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    spec = importlib.util.spec_from_file_location('_conftest_copy', CONFTEST)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.DOMAINS


def test_explicit_block_is_split_between_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    assert _block(monkeypatch, CVJ_TEST_DOMAINS='110-129') == list(range(110, 130))
    w0 = _block(monkeypatch, CVJ_TEST_DOMAINS='110-129', PYTEST_XDIST_WORKER='gw0',
                PYTEST_XDIST_WORKER_COUNT='2')
    w1 = _block(monkeypatch, CVJ_TEST_DOMAINS='110-129', PYTEST_XDIST_WORKER='gw1',
                PYTEST_XDIST_WORKER_COUNT='2')
    assert w0 == list(range(110, 130, 2)) and w1 == list(range(111, 130, 2))


def test_domain_id_block_is_ten_ids_per_worker(monkeypatch: pytest.MonkeyPatch) -> None:
    blocks = [_block(monkeypatch, ROS_DOMAIN_ID='150', PYTEST_XDIST_WORKER=f'gw{k}',
                     PYTEST_XDIST_WORKER_COUNT='3') for k in range(3)]
    assert all(len(b) == 10 for b in blocks)
    assert sorted(sum(blocks, [])) == list(range(150, 180))


def test_derived_block_is_shared_by_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    common = dict(PYTEST_XDIST_WORKER_COUNT='2', PYTEST_XDIST_TESTRUNUID='9f3a0c')
    w0 = _block(monkeypatch, PYTEST_XDIST_WORKER='gw0', **common)
    w1 = _block(monkeypatch, PYTEST_XDIST_WORKER='gw1', **common)
    assert not set(w0) & set(w1) and len(w0) == len(w1) == 10
    assert max(w0 + w1) - min(w0 + w1) == 19 and max(w0 + w1) <= 232


def test_too_small_block_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match='fewer ids than the 2 pytest-xdist workers'):
        _block(monkeypatch, CVJ_TEST_DOMAINS='120', PYTEST_XDIST_WORKER='gw0',
               PYTEST_XDIST_WORKER_COUNT='2')
