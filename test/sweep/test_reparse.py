"""cvj_ros.sweep.reparse: a variant parsed from the reference scene and its changed
elements is parse_scene's Scene, and an invalid value raises parse_scene's error."""
from __future__ import annotations

from typing import Any

import pytest

from cvj_ros.commands.sweep import load_scene_data
from cvj_ros.errors import CvjError
from cvj_ros.physics.scene import find_scene, parse_scene
from cvj_ros.sweep.batch import element_local, variant_dict
from cvj_ros.sweep.reparse import Reparser
from cvj_ros.sweep.spec import build_sweep


def full(base: Any, keys: Any, values: Any) -> tuple[str, Any]:
    """('ok', Scene) or ('error', the error's text) of the full parse."""
    try:
        return 'ok', parse_scene(variant_dict(base, keys, values))
    except CvjError as exc:
        return 'error', str(exc)


def reparsed(rp: Reparser, values: Any) -> tuple[str, Any]:
    try:
        return 'ok', rp.parse(values)
    except CvjError as exc:
        return 'error', str(exc)


def grid(sets: list[str]) -> tuple[Any, Any, list[tuple[Any, ...]]]:
    sw = build_sweep(load_scene_data(find_scene('kavz685_lever')), sets)
    return sw.base, tuple(a.keys for a in sw.axes), [tuple(v) for v in sw.variants]


def test_scenes_and_errors_equal_parse_scene() -> None:
    # alpha 95 deg and a zero or negative stiffness are invalid (two elements, both orders
    # of failure); a fixed duration is a non-local key at its reference value
    base, keys, variants = grid(['duration=0.3', 'driveline[coupling].params.alpha_deg=0,15,30,95',
                                 'driveline[bushings].stiffness=300,0,-5,3000'])
    rp = Reparser(base, keys, variants[0], element_local(keys))
    assert rp.scene is not None
    errors = 0
    for _pass in range(2):      # the second pass reads the kept elements
        for v in variants:
            want = full(base, keys, v)
            assert reparsed(rp, v) == want, v
            errors += want[0] == 'error'
    assert errors == 2 * (4 * 4 - 3 * 2)
    # the error names the element that fails first in the driveline's order
    bad = reparsed(rp, (0.3, 95, 0))
    assert bad == full(base, keys, (0.3, 95, 0)) and 'driveline[1].stiffness' in bad[1]


def test_the_reference_values_and_other_keys() -> None:
    base, keys, variants = grid(['solver.rtol=1e-6,1e-5', 'driveline[coupling].params.alpha_deg=10,20'])
    rp = Reparser(base, keys, variants[0], element_local(keys))
    assert rp.parse(variants[0]) is rp.scene            # nothing changed
    for v in variants:          # rtol is not element-local: parsed in full when it differs
        assert reparsed(rp, v) == full(base, keys, v)
    assert len(rp.elements) == 1        # alpha 20 at the reference rtol only


def test_an_invalid_reference_parses_every_variant_in_full() -> None:
    base, keys, variants = grid(['driveline[coupling].params.alpha_deg=95,10,20'])
    rp = Reparser(base, keys, variants[0], element_local(keys))
    assert rp.scene is None
    for v in variants:
        assert reparsed(rp, v) == full(base, keys, v)
    assert not rp.elements


@pytest.mark.parametrize('value', [20, 20.0, '20'])
def test_value_types_are_told_apart(value: Any) -> None:
    """1 and 1.0 and '1' are kept apart (a string angle is an error, a number is not)."""
    base, keys, variants = grid(['driveline[coupling].params.alpha_deg=10,15'])
    rp = Reparser(base, keys, variants[0], element_local(keys))
    rp.parse((20.0,))
    assert reparsed(rp, (value,)) == full(base, keys, (value,))
