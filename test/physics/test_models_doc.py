"""README shows one example per engine and load model (issue 14 item 5); every example line
must build, so the README cannot drift from the code."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from cvj_ros.physics.engine import engine_from_spec
from cvj_ros.physics.load import load_from_spec

README = Path(__file__).resolve().parents[2] / 'README.md'
BLOCK = next(b for b in re.findall(r'```yaml\n(.*?)```', README.read_text(), flags=re.S)
             if 'model: brake_steps' in b)
LINES = [line for line in BLOCK.splitlines() if line.startswith(('engine:', 'load:'))]


def test_every_model_has_an_example() -> None:
    for model in ('linear', 'map', 'constant', 'random', 'fourier', 'road', 'brake_steps',
                  'time_series'):
        assert any(f'model: {model}' in line for line in LINES), model


@pytest.mark.parametrize('line', LINES)
def test_example_builds(line: str) -> None:
    spec = yaml.safe_load(line)
    if 'engine' in spec:
        eng = engine_from_spec(spec['engine'], field='engine')
        assert abs(eng.torque(0.0, 100.0, 0.0)) < 1e4
    else:
        load = load_from_spec(spec['load'], seed=1, field='load')
        assert abs(load.torque(0.5, 30.0, 0.2)) < 1e6
