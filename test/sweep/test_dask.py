"""The same sweep on a Dask distributed cluster (LocalCluster of 2 worker processes, one
thread each) gives the same results.csv bytes as a serial run on the per-variant path,
through the API (a Client) and through `cvj-sim sweep --cluster tcp://...` (the workers
run the batched path: the grid changes the fidelity decision and holds an invalid
variant, so it has several templates and fallbacks)."""
from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from cvj_ros.cli import main
from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.physics.scene import find_scene
from cvj_ros.sweep.run import (DaskExecutor, Job, RunOptions, SerialExecutor, execute,
                              run_chunk)
from cvj_ros.sweep.spec import build_sweep

distributed = pytest.importorskip('distributed')

REPO = Path(__file__).resolve().parents[2]
SETS = ['duration=0.5', 'accuracy_target=0.01', 'driveline[coupling].params.alpha_deg=10,20,30,95',
        'driveline[bushings].stiffness=500,900,300000']


@pytest.fixture(scope='module')
def client() -> Iterator[object]:
    # the workers are new processes: they must import this checkout's cvj_ros
    old = os.environ.get('PYTHONPATH')
    os.environ['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), old) if p)
    cluster = distributed.LocalCluster(processes=True, n_workers=2, threads_per_worker=1,
                                       dashboard_address=None, host='127.0.0.1')
    c = distributed.Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()
        if old is None:
            os.environ.pop('PYTHONPATH', None)
        else:
            os.environ['PYTHONPATH'] = old


class PerVariantExecutor(SerialExecutor):
    """The serial executor on the per-variant path (run_variant for every variant)."""

    def map(self, job: Job, work: list[list[tuple[int, Sequence[Any]]]]) -> Iterator[list[Any]]:
        for chunk in work:
            yield run_chunk(job, chunk, batched=False)


@pytest.fixture(scope='module')
def serial_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    out = tmp_path_factory.mktemp('serial')
    sweep = build_sweep(load_scene_data(find_scene('kavz685_lever')), SETS)
    execute(sweep, RunOptions(), out, executor=PerVariantExecutor(),
            scene_source=str(find_scene('kavz685_lever')))
    return (out / 'results.csv').read_bytes()


def test_dask_client_same_bytes(client: object, serial_bytes: bytes, tmp_path: Path) -> None:
    sweep = build_sweep(load_scene_data(find_scene('kavz685_lever')), SETS)
    report = execute(sweep, RunOptions(), tmp_path, executor=DaskExecutor(client),
                     scene_source=str(find_scene('kavz685_lever')))
    assert report.complete and report.executor == 'dask' and report.workers == 2
    assert (tmp_path / 'results.csv').read_bytes() == serial_bytes


def test_cli_cluster_address_same_bytes(client: object, serial_bytes: bytes, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    address = client.scheduler.address      # type: ignore[attr-defined]
    assert address.startswith('tcp://127.0.0.1:')
    args = [x for s in SETS for x in ('--set', s)]
    assert main(['sweep', 'kavz685_lever', *args, '--out', str(tmp_path), '--cluster', address,
                 '--no-plots']) == 0
    assert f'on Dask cluster {address}' in capsys.readouterr().err
    assert (tmp_path / 'results.csv').read_bytes() == serial_bytes
