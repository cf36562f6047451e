"""Test-wide settings: keep all DDS traffic on this machine, one ROS domain per test.

Domains. Every test runs with its own ``ROS_DOMAIN_ID`` (autouse fixture :func:`ros_domain`),
taken in turn from a per-run block of ids, and subprocesses inherit it through ``os.environ``.
So participants a test leaves behind (a slow echo process, a context not yet shut down) can
never answer the next test's discovery, and a test that fails cannot make the next one fail.
The block:

* ``CVJ_TEST_DOMAINS=LO-HI`` (inclusive), e.g. ``110-129``: exactly these ids;
* else ``ROS_DOMAIN_ID=B`` from the environment: ``B .. B + CVJ_TEST_DOMAIN_SPAN - 1``
  (span 10 by default);
* else (or with ``CVJ_TEST_FRESH_DOMAIN`` set) a block of 10 derived from the pid inside
  1..100 (ids <= 101 allow any participant count per domain with Fast DDS's port mapping).

Ids are capped at 232 (the largest the default RTPS port mapping allows). A block of ten
means a domain is reused only ten tests later, long after that test's processes ended.
Under pytest-xdist (``make test``: two workers) the block is ten ids per worker and each
worker takes every N-th id of it (worker k of N: ids k, k + N, ...), so no two workers ever
share a domain; the pid-derived block is derived from the run's id, which the workers share.
Module-scoped fixtures that start processes (e2e runs) run between tests, one at a time,
on the block's first id.

Signals. A suite started in the background of a non-interactive shell (``make test &``,
some CI runners) inherits SIGINT *ignored*, and an ignored disposition survives exec: every
process a test starts would ignore the Ctrl-C the signal tests send it. pytest therefore
takes SIGINT back (Python's default handler) when it finds it ignored, so the processes it
starts get the default disposition.
"""
from __future__ import annotations

import itertools
import os
import signal

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

MAX_DOMAIN_ID = 232          # RTPS port mapping: 7400 + 250 * id + offsets must stay < 65536


def _domain_block() -> list[int]:
    """The ROS domain ids this pytest run hands out, in order (see the module docstring)."""
    spec = os.environ.get('CVJ_TEST_DOMAINS', '').strip()
    if spec:
        lo_s, _, hi_s = spec.partition('-')
        lo, hi = int(lo_s), int(hi_s or lo_s)
    else:
        span = int(os.environ.get('CVJ_TEST_DOMAIN_SPAN', '10')) * _xdist_worker()[1]
        if os.environ.get('ROS_DOMAIN_ID') and not os.environ.get('CVJ_TEST_FRESH_DOMAIN'):
            lo = int(os.environ['ROS_DOMAIN_ID'])
        else:
            run = os.environ.get('PYTEST_XDIST_TESTRUNUID')   # shared by the workers
            lo = 1 + ((int(run, 16) if run else os.getpid()) % 10) * 10
        hi = lo + span - 1
    lo, hi = max(0, lo), min(MAX_DOMAIN_ID, hi)
    if hi < lo:
        raise ValueError(f'CVJ_TEST_DOMAINS: empty block {lo}-{hi}')
    ids = list(range(lo, hi + 1))
    worker, count = _xdist_worker()
    if count > 1:
        if len(ids) < count:
            raise ValueError(f'CVJ_TEST_DOMAINS: block {lo}-{hi} has fewer ids than the '
                             f'{count} pytest-xdist workers')
        ids = ids[worker::count]
    return ids


def _xdist_worker() -> tuple[int, int]:
    """(index, count) of this pytest-xdist worker (``gw0`` -> 0), (0, 1) without xdist."""
    name = os.environ.get('PYTEST_XDIST_WORKER', '')
    count = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1)
    return (int(name[2:]) if name.startswith('gw') else 0), max(1, count)


DOMAINS = _domain_block()
os.environ['ROS_DOMAIN_ID'] = str(DOMAINS[0])
_next_domain = itertools.cycle(DOMAINS[1:] or DOMAINS)


import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """A ROS domain id of its own for this test, exported as ROS_DOMAIN_ID (restored after)."""
    domain = next(_next_domain)
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    return domain


def _read_process_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, full command line) of every process, from /proc (not `ps`,
    which cuts its args column at $COLUMNS)."""
    from pathlib import Path
    table: dict[int, tuple[int, str]] = {}
    for d in Path('/proc').iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / 'stat').read_text()
            cmd = (d / 'cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
        except OSError:   # exited meanwhile
            continue
        ppid = int(stat.rsplit(')', 1)[1].split()[1])   # after "(comm)": state, ppid
        table[int(d.name)] = (ppid, cmd)
    return table


@pytest.fixture
def process_table():
    """A function returning pid -> (parent pid, full command line) of every process now."""
    return _read_process_table


@pytest.fixture
def shipped_scene_with(tmp_path):
    """A function (scene, old, new) -> path of the shipped ``scene``'s file with its one
    ``old`` text replaced by ``new``, written in the test's tmp_path."""
    from cvj_ros.physics.scene import shipped_scenes

    def write(scene: str, old: str, new: str):
        text = shipped_scenes()[scene].read_text()
        assert text.count(old) == 1, (scene, old)
        path = tmp_path / f'{scene}_changed.yaml'
        path.write_text(text.replace(old, new))
        return path
    return write


@pytest.fixture
def ctx():
    """A fresh rclpy Context per test (initialised, shut down afterwards). rclpy is imported
    here, not at module level, so physics-only test runs do not need it."""
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)
