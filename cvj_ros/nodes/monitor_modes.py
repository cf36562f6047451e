"""The driveline's operating state as the monitor sees it: steady running or a transient mode.

A scene with a clutch, gearbox or brakes passes through states that are not faults: the
vehicle held at rest by its brakes, a clutch slipping while it engages, neutral and a shift
in progress, an engine stall. The speed-nonuniformity limits (w_max - w_min)/w_mean of
Davidbaev et al. 2023 (sec. 4) describe a driveline in steady running (a periodic speed about
a constant mean); over a window that holds a launch or a shift the same ratio measures the
speed change of the transient, not a nonuniformity. :class:`DrivelineStates` reads the
coupling node's loop status (``clutch_state.*``, ``brake_state.*``, ``gear.*``, ``shifting``,
``stall``, ``mode_events``, ``<wheel>.slip``, published every ``diagnostics_every`` steps)
and says, for a window, whether it lies wholly in steady running: no clutch slipping, no
wheel held by its brake, no wheel spinning (slip ratio beyond :data:`WHEELSPIN_SLIP`), a
gear engaged and no shift running, no stall, and no mode event between the statuses.
Outside steady running the monitor reports the nonuniformity without judging it.
rclpy-free.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ['DrivelineStates', 'MODE_ELEMENTS', 'WHEELSPIN_SLIP', 'scene_has_modes']

#: scene element types whose modes make a driveline leave steady running
MODE_ELEMENTS = frozenset({'clutch', 'gearbox', 'brake'})
#: |slip ratio| above which a wheel spins (traction-limited, past the tyre's force peak: the
#: magic formula of the shipped vehicle scenes, B 10, C 1.9, E 0.97, peaks at 0.18)
WHEELSPIN_SLIP = 0.2


def scene_has_modes(elements: Iterable[Mapping[str, Any]]) -> bool:
    """A scene dict's elements (``scene_elements``) hold a clutch, a gearbox or a brake."""
    return any(el.get('type') in MODE_ELEMENTS for el in elements)


class DrivelineStates:
    """Modes from the coupling node's loop statuses; see the module docstring.

    ``expect_modes``: the scene has mode elements, so a window before the first loop status
    is not known to be steady."""

    def __init__(self, expect_modes: bool = False) -> None:
        self.expect_modes = expect_modes
        self.modes: dict[str, str] = {}       # the latest status's clutch/brake/gear/shift/stall
        self.seen = False                     # a loop status with modes arrived
        self.unsteady_ns: int | None = None   # stamp of the latest status outside steady running
        self.unsteady_why = ''                # what it was
        self._events: int | None = None       # mode_events of the previous status

    def take(self, stamp_ns: int, values: Mapping[str, str]) -> None:
        """One coupling-node loop status (key -> value strings) stamped ``stamp_ns``."""
        modes = {k: v for k, v in values.items()
                 if k.startswith(('clutch_state.', 'brake_state.', 'gear.'))
                 or k.endswith('.slip') or k in ('shifting', 'stall')}
        if not modes:
            return
        self.seen = True
        self.modes = modes
        why = self._transient(modes)
        events = values.get('mode_events')
        try:
            n = int(events) if events is not None else None
        except ValueError:
            n = None
        if n is not None and self._events is not None and n > self._events and not why:
            why = f'{n - self._events} mode event(s) since the last status'
        if n is not None:
            self._events = n
        if why:
            self.unsteady_ns = stamp_ns
            self.unsteady_why = why

    @staticmethod
    def _transient(modes: Mapping[str, str]) -> str:
        """What keeps ``modes`` out of steady running ('' in steady running)."""
        if modes.get('stall'):
            return 'engine stalled'
        out = []
        slipping = [k.split('.', 1)[1] for k, v in modes.items()
                    if k.startswith('clutch_state.') and v != 'stuck']
        if slipping:
            out.append(f'{", ".join(slipping)} slipping')
        held = [k.split('.', 1)[1] for k, v in modes.items()
                if k.startswith('brake_state.') and v == 'stuck']
        if held:
            out.append(f'{", ".join(held)} holding (vehicle at rest)')
        spinning = []
        for k, v in modes.items():
            try:
                if k.endswith('.slip') and abs(float(v)) > WHEELSPIN_SLIP:
                    spinning.append(k[:-len('.slip')])
            except ValueError:
                pass
        if spinning:
            out.append(f'{", ".join(spinning)} spinning')
        if modes.get('shifting', '0') not in ('0', ''):
            out.append('shift running')
        neutral = [k.split('.', 1)[1] for k, v in modes.items()
                   if k.startswith('gear.') and v == '0']
        if neutral and 'shift running' not in out:
            out.append(f'{", ".join(neutral)} in neutral')
        return ', '.join(out)

    def not_steady(self, window_start_ns: int) -> str:
        """Why a window starting at ``window_start_ns`` is not wholly steady running ('' when
        it is, or when the scene has no modes)."""
        if not self.seen:
            return 'modes not known yet' if self.expect_modes else ''
        if self.unsteady_ns is not None and self.unsteady_ns >= window_start_ns:
            return self.unsteady_why
        return ''

    def state_line(self) -> str:
        """The current state in a few words ('steady running' or the transient)."""
        if not self.seen:
            return 'modes not known yet'
        return self._transient(self.modes) or 'steady running'
