"""Every ```yaml block of README.md and docs/*.md is a scene the program accepts: a whole
scene as written; a fragment (some top-level keys, or a list of driveline elements) merged
into a minimal two-inertia scene. An error-message example quoted in the docs for a bad
scene is the program's text for that input (test/test_docs_commands.py checks the commands)."""
from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest
import yaml

from cvj_ros.errors import SceneError
from cvj_ros.physics.scene import parse_scene

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]

BASE = {'name': 'doc_fragment', 'duration': 0.1, 'exchange_step': 0.001,
        'engine': {'model': 'linear', 'm1': 10.0, 'k1': 0.1},
        'load': {'model': 'constant', 'torque': 5.0},
        'driveline': [{'type': 'inertia', 'name': 'doc_in', 'J': 0.1},
                      {'type': 'spring', 'name': 'doc_spring', 'stiffness': 1000.0, 'damping': 1.0},
                      {'type': 'inertia', 'name': 'doc_out', 'J': 0.2}]}


def _yaml_blocks() -> list[tuple[str, str]]:
    out = []
    for path in DOCS:
        lines = path.read_text(encoding='utf-8').splitlines()
        i = 0
        while i < len(lines):
            if lines[i].strip().startswith('```yaml'):
                j = i + 1
                while j < len(lines) and not lines[j].strip().startswith('```'):
                    j += 1
                out.append((f'{path.relative_to(ROOT)}:{i + 1}', '\n'.join(lines[i + 1:j])))
                i = j
            i += 1
    return out


def _as_scene(data: object) -> dict:
    if isinstance(data, dict) and 'name' in data and 'driveline' in data:
        return data
    scene = copy.deepcopy(BASE)
    if isinstance(data, list):            # driveline elements: between the two inertias
        elements = list(data)
        if elements and elements[0].get('type') != 'inertia':
            elements.insert(0, BASE['driveline'][0])
        if elements and elements[-1].get('type') != 'inertia':
            elements.append(BASE['driveline'][-1])
        scene['driveline'] = elements
    else:
        assert isinstance(data, dict), type(data)
        if 'shift_schedule' in data and 'vehicle' not in data:   # vehicle scenes only
            from cvj_ros.physics.scene import find_scene
            from cvj_ros.textfile import load_yaml_bounded, read_text_file
            path = find_scene('launch_clutch')
            scene = load_yaml_bounded(read_text_file(path, what='scene file'), str(path))
            scene.update(data)
            return scene
        if 'vehicle' in data:
            scene.pop('load')
        scene.update(data)
    return scene


BLOCKS = _yaml_blocks()


def test_the_docs_have_yaml_blocks() -> None:
    assert len(BLOCKS) >= 8


@pytest.mark.parametrize(('where', 'text'), BLOCKS, ids=[w for w, _ in BLOCKS])
def test_yaml_block_is_an_accepted_scene(where: str, text: str) -> None:
    parse_scene(_as_scene(yaml.safe_load(text)))


_SCENE_ERROR = re.compile(r'cvj-sim: error: (driveline\[(\d)\]\.params\.beta_deg: must be[^`|]*?'
                          r'got (\d+) deg \([\d.]+ rad\))')


def test_quoted_hooke_angle_errors_are_the_program_text() -> None:
    """`cvj-sim: error: driveline[2].params.beta_deg: must be ... got 95 deg (...)` in the
    docs: a Hooke joint at that angle as element 2 gives exactly that text."""
    quoted = [(path.name, m) for path in DOCS
              for m in _SCENE_ERROR.finditer(path.read_text(encoding='utf-8'))]
    assert quoted
    for name, m in quoted:
        scene = copy.deepcopy(BASE)
        index, angle = int(m.group(2)), float(m.group(3))
        scene['driveline'] = [BASE['driveline'][0],
                              {'type': 'spring', 'name': 's', 'stiffness': 1000.0, 'damping': 1.0},
                              {'type': 'joint', 'name': 'j', 'kind': 'hooke',
                               'params': {'beta_deg': angle}},
                              BASE['driveline'][-1]]
        assert index == 2
        with pytest.raises(SceneError) as err:
            parse_scene(scene)
        assert str(err.value) == m.group(1).strip(), name
