"""DrivelineStates: the monitor's steady-running judgement from the coupling node's loop
status (a standing start, a shift and a stall are states, not nonuniformity errors)."""
from __future__ import annotations

from cvj_ros.nodes.monitor_modes import DrivelineStates, scene_has_modes
from cvj_ros.nodes.parameters import scene_elements

S = 1_000_000_000
HELD = {'clutch_state.clutch': 'slip+', 'gear.gearbox': '1', 'brake_state.brake_left': 'stuck',
        'brake_state.brake_right': 'stuck', 'shifting': '0', 'stall': '', 'mode_events': '2'}
LAUNCH = dict(HELD, **{'brake_state.brake_left': 'slip+', 'brake_state.brake_right': 'slip+',
                       'mode_events': '4'})
LOCKED = dict(LAUNCH, **{'clutch_state.clutch': 'stuck', 'mode_events': '5'})
SHIFT = dict(LOCKED, **{'shifting': '1', 'clutch_state.clutch': 'slip+', 'mode_events': '7'})
NEUTRAL = dict(SHIFT, **{'gear.gearbox': '0', 'mode_events': '8'})


def test_a_standing_start_is_not_steady_running_until_a_window_after_the_lock() -> None:
    st = DrivelineStates(expect_modes=True)
    assert st.not_steady(0) == 'modes not known yet'
    st.take(100_000_000, HELD)
    assert 'brake_left, brake_right holding (vehicle at rest)' in st.not_steady(0)
    assert 'clutch slipping' in st.state_line()
    st.take(2 * S, LAUNCH)
    assert st.not_steady(S + S // 2) == 'clutch slipping'
    st.take(3 * S, LOCKED)               # one more event (the lock) since the last status
    assert st.not_steady(2 * S + 1) == '1 mode event(s) since the last status'
    st.take(3 * S + S // 10, LOCKED)
    assert st.state_line() == 'steady running'
    assert st.not_steady(3 * S + 1) == ''          # a window wholly after the lock
    assert st.not_steady(3 * S) != ''              # one that still holds it


def test_a_shift_and_neutral_and_a_stall_are_named() -> None:
    st = DrivelineStates()
    st.take(S, LOCKED)
    st.take(2 * S, SHIFT)
    assert st.not_steady(S) == 'clutch slipping, shift running'
    st.take(3 * S, NEUTRAL)
    assert st.not_steady(S) == 'clutch slipping, shift running'
    st.take(4 * S, dict(LOCKED, **{'gear.gearbox': '0', 'mode_events': '8'}))
    assert st.not_steady(S) == 'gearbox in neutral'
    st.take(5 * S, dict(LOCKED, stall='engine stalled at t=5 s', mode_events='9'))
    assert st.not_steady(4 * S) == 'engine stalled'


def test_wheelspin_is_a_transient() -> None:
    """A wheel past the tyre's force peak (launch on the grade: slip ratio 0.6-0.7 right after
    the clutch locks) is not steady running; the regularised slip of a wheel at rest is."""
    st = DrivelineStates()
    st.take(S, dict(LOCKED, **{'wheel_left.slip': '0.0102', 'wheel_right.slip': '0.0102'}))
    assert st.state_line() == 'steady running'
    st.take(2 * S, dict(LOCKED, **{'wheel_left.slip': '0.61', 'wheel_right.slip': '0.05'}))
    assert st.not_steady(S) == 'wheel_left spinning'
    st.take(3 * S, dict(LOCKED, **{'wheel_left.slip': '-0.3', 'wheel_right.slip': '0.05'}))
    assert st.not_steady(2 * S + 1) == 'wheel_left spinning'
    st.take(4 * S, dict(LOCKED, **{'wheel_left.slip': '0.05', 'wheel_right.slip': '0.05'}))
    assert st.not_steady(3 * S + 1) == ''


def test_a_plain_scene_is_always_judged() -> None:
    st = DrivelineStates(expect_modes=False)
    assert st.not_steady(0) == ''
    st.take(S, {'energy_residual': '1e-12', 'steps': '1000'})     # no modes in a plain status
    assert not st.seen and st.not_steady(0) == ''


def test_scene_has_modes() -> None:
    plain = [{'type': 'inertia', 'name': 'a'}, {'type': 'spring', 'name': 's'}]
    assert not scene_has_modes(scene_elements(plain))
    tree = [{'type': 'clutch', 'name': 'c'},
            {'type': 'differential', 'name': 'd',
             'left': [{'type': 'wheel', 'name': 'wl'}, {'type': 'brake', 'name': 'bl'}],
             'right': [{'type': 'wheel', 'name': 'wr'}]}]
    assert scene_has_modes(scene_elements(tree))
    assert scene_has_modes(scene_elements([{'type': 'differential', 'name': 'd', 'left': [
        {'type': 'brake', 'name': 'b'}], 'right': []}]))
