"""A bad ROS_DOMAIN_ID is one line naming the variable and exit 2 in every entry point that
joins a ROS domain (``cvj-sim run``, ``cvj-sim record``, a node started by hand), instead of
the DDS layer's own log lines (Fast DDS cannot open ports for a domain over 232)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cvj_ros.errors import CvjError
from cvj_ros.nodes.qos import MAX_DOMAIN_ID, domain_id

BIN = Path(sys.executable).parent
SCENE = Path(__file__).resolve().parents[2] / 'config' / 'scenes' / 'stiff.yaml'


def test_domain_id_values() -> None:
    assert domain_id({}) == 0
    assert domain_id({'ROS_DOMAIN_ID': ''}, default=7) == 7
    assert domain_id({'ROS_DOMAIN_ID': ' 12 '}) == 12
    assert domain_id({'ROS_DOMAIN_ID': str(MAX_DOMAIN_ID)}) == MAX_DOMAIN_ID
    # Fast DDS's ports for domain d: 7400 + 250 d + offsets 0, 1, 10, 11 (+ 2 per participant
    # id); the user unicast port of participant 0 on d = 233 would pass 65535
    assert 7400 + 250 * MAX_DOMAIN_ID + 11 <= 65535 < 7400 + 250 * (MAX_DOMAIN_ID + 1) + 11


@pytest.mark.parametrize('raw, part', [('abc', 'must be an integer'), ('1.5', 'must be an integer'),
                                       ('233', 'from 0 to 232'), ('-1', 'from 0 to 232'),
                                       ('99999999999999999999', 'from 0 to 232')])
def test_domain_id_rejects(raw: str, part: str) -> None:
    with pytest.raises(CvjError) as err:
        domain_id({'ROS_DOMAIN_ID': raw})
    assert str(err.value).startswith('ROS_DOMAIN_ID: ') and part in str(err.value)


def _one_line(cmd: list[str], prog: str, tmp_path: Path) -> None:
    env = dict(os.environ, ROS_DOMAIN_ID='233')
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.splitlines()
    assert lines == [f'{prog}: error: ROS_DOMAIN_ID: must be from 0 to 232 (DDS ports 7400 + 250 x '
                     f'domain must stay under 65536), got 233'], proc.stderr
    assert 'Traceback' not in proc.stdout


def test_run_with_domain_over_232(tmp_path: Path) -> None:
    _one_line([str(BIN / 'cvj-sim'), 'run', str(SCENE), '--out', str(tmp_path / 'r')],
              'cvj-sim', tmp_path)
    assert not (tmp_path / 'r' / 'bag').exists()


def test_record_with_domain_over_232(tmp_path: Path) -> None:
    _one_line([str(BIN / 'cvj-sim'), 'record', str(tmp_path / 'rec')], 'cvj-sim', tmp_path)
    assert not (tmp_path / 'rec' / 'bag').exists()


def test_node_with_domain_over_232(tmp_path: Path) -> None:
    _one_line([str(BIN / 'engine_node')], 'engine_node', tmp_path)
