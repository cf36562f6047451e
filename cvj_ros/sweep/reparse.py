"""A sweep variant's scene from a parsed reference scene, re-validating only the elements
its keys change: :func:`cvj_ros.physics.scene.parse_scene`'s result and errors without
parsing the whole scene again.

:class:`Reparser` parses the reference variant (the job's base with a first variant's
values) once. A variant whose keys differ from the reference only in *element-local*
keys (:func:`cvj_ros.sweep.batch.element_local`: one field of one ``driveline[i]``
element, at most one such key per element; the others equal the reference's) has the
reference's scene dict except in those elements. parse_scene validates the top level
(unchanged: it passed), then the elements in order (an unchanged element passed), then
the chain checks. So the variant's parse is: each changed element parsed alone by the
same element parser, in index order (the first that raises gives parse_scene's error),
the unchanged elements reused, and the chain checks run again on the new chain
(``check_layout``, ``check_hooke_phasing``; the names and element types cannot change, so
the duplicate-name and mode-element checks give the reference's verdict). A changed
element's parse is kept per (element, value): a grid repeats each value.
Anything else - a vehicle scene, a scene with modes, a reference that does not parse, a
non-local key away from its reference value - is parsed in full by parse_scene.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from cvj_ros.sweep.batch import _value_key, variant_dict

__all__ = ['Reparser']

#: kept element parses per reparser (a grid axis holds a few hundred values at most)
MAX_ELEMENTS = 4096


class Reparser:
    """parse_scene of a job's variants (base dict, key paths, values per variant)."""

    def __init__(self, base: Mapping[str, Any], keys: Sequence[Sequence[str | int]],
                 values: Sequence[Any], local: Sequence[bool]) -> None:
        from cvj_ros.physics.scene import parse_scene
        self.base = base
        self.keys = [tuple(k) for k in keys]
        self.local = list(local)
        self.ref_values = tuple(values)
        self.ref_keys = [_value_key(v) for v in values]
        self.ref_dict = variant_dict(base, self.keys, values)
        self.elements: dict[tuple[int, tuple[str, str]], Any] = {}
        self.scene = None
        try:
            scene = parse_scene(self.ref_dict)
        except Exception:       # noqa: BLE001  (every variant is parsed in full)
            return
        if not scene.is_tree and not scene.has_modes and any(self.local):
            self.scene = scene

    def parse(self, values: Sequence[Any],
              vkeys: Sequence[tuple[str, str]] | None = None) -> Any:
        """parse_scene(variant_dict(base, keys, values)): the same Scene (equal field by
        field) or the same SceneError. ``vkeys``: the values' _value_key when the caller has
        them."""
        from cvj_ros.physics.scene import parse_scene
        changed: list[tuple[int, int, Any, Any]] = []   # (element, axis, value, value key)
        if self.scene is not None:
            if vkeys is None:
                vkeys = [_value_key(v) for v in values]
            for axis, (v, vk) in enumerate(zip(values, vkeys)):
                if vk == self.ref_keys[axis]:
                    continue
                if not self.local[axis]:
                    changed = []
                    break
                changed.append((int(self.keys[axis][1]), axis, v, vk))
            else:
                return self._patched(sorted(changed, key=lambda c: c[0]))
        return parse_scene(variant_dict(self.base, self.keys, values))

    def _element(self, index: int, axis: int, value: Any, vk: tuple[str, str]) -> Any:
        """The parsed element ``index`` with ``axis`` at ``value`` (kept), or raises its
        SceneError (not kept: an invalid value is parsed again, as the full path does)."""
        from cvj_ros.physics.scene import parse_element
        key = (index, vk)
        el = self.elements.get(key)
        if el is None:
            raw = variant_dict(self.ref_dict, [self.keys[axis]], [value])['driveline'][index]
            el = parse_element(raw, f'driveline[{index}]')     # raises as parse_scene would
            if len(self.elements) >= MAX_ELEMENTS:
                self.elements.clear()
            self.elements[key] = el
        return el

    def _patched(self, changed: list[tuple[int, int, Any, Any]]) -> Any:
        from cvj_ros.physics.scene import check_hooke_phasing, check_layout
        if not changed:
            return self.scene
        chain = list(self.scene.driveline)
        for index, axis, value, vk in changed:
            chain[index] = self._element(index, axis, value, vk)
        driveline = tuple(chain)
        check_layout(driveline)
        check_hooke_phasing(driveline)
        return dataclasses.replace(self.scene, driveline=driveline)
