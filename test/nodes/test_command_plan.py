"""Command topics without ROS: the schedule sampled on exchange steps (what driver_node plays
and the coupling node awaits), checked decoding of Float64 / Int8 / Clock bytes, the inbox."""
from __future__ import annotations

import struct

import pytest

from cvj_ros.nodes.command_inbox import CommandInbox
from cvj_ros.nodes.command_plan import (CommandError, CommandPlan, check_command,
                                        decode_clock_ns, decode_command)
from cvj_ros.physics.hybrid.commands import CommandSchedule

LE = b'\x00\x01\x00\x00'
BE = b'\x00\x00\x00\x00'


def _plan(rows, steps=10, h_ns=1_000_000) -> CommandPlan:
    return CommandPlan.from_schedule(CommandSchedule(rows), h_ns, steps)


def test_plan_samples_ramps_at_the_steps_and_sends_only_changes() -> None:
    plan = _plan([(0.0, {'clutch': 1.0, 'gear': 1, 'brake': 1.0}),
                  (0.002, {'clutch': 1.0}), (0.004, {'clutch': 0.0}), (0.005, {'gear': 2})])
    assert plan.channels == ('clutch', 'gear', 'brake')
    assert plan.at(0) == (('clutch', 1.0), ('gear', 1.0), ('brake', 1.0))
    assert plan.at(1) == plan.at(2) == ()
    assert plan.at(3) == (('clutch', 0.5),)          # the ramp 0.002 -> 0.004 s sampled at t_3
    assert plan.at(4) == (('clutch', 0.0),)
    assert plan.at(5) == (('gear', 2.0),)
    assert [k for k, _row in plan] == [0, 3, 4, 5]


def test_decoders_read_both_byte_orders_and_refuse_junk_as_malformed() -> None:
    assert decode_command('clutch', LE + struct.pack('<d', 0.25)) == 0.25
    assert decode_command('brake', BE + struct.pack('>d', 0.75)) == 0.75
    assert decode_command('gear', LE + struct.pack('<b', -1) + b'\x00\x00\x00') == -1.0
    assert decode_clock_ns(LE + struct.pack('<iI', 2, 5)) == 2_000_000_005
    for channel, data in (('clutch', b''), ('clutch', b'\x07junk'), ('clutch', LE + b'\x00' * 4),
                          ('gear', LE), ('brake', LE + b'\x00' * 70000)):
        with pytest.raises(CommandError) as exc:
            decode_command(channel, data)
        assert exc.value.malformed


@pytest.mark.parametrize('channel, value, why', [
    ('clutch', 1.5, 'must be in 0..1'), ('brake', float('nan'), 'finite'),
    ('throttle', -0.1, 'must be in 0..1'), ('gear', 2.5, 'integer gear'), ('gear', 5.0, '-1..4'),
    ('gear', -2.0, 'integer gear')])
def test_out_of_range_values_are_refused_not_malformed(channel, value, why) -> None:
    with pytest.raises(CommandError, match=why) as exc:
        check_command(channel, value, n_gears=4)
    assert not exc.value.malformed


def test_inbox_awaits_each_steps_samples_and_checks_them_against_the_plan() -> None:
    plan = _plan([(0.0, {'clutch': 1.0, 'gear': 1}), (0.003, {'gear': 2})])
    box = CommandInbox(plan, n_gears=3)
    assert not box.ready(0) and box.missing(0) == ['/driveline/clutch', '/driveline/gear']
    box.offer('clutch', LE + struct.pack('<d', 1.0))
    assert not box.ready(0)
    box.offer('gear', LE + struct.pack('<b', 1))
    assert box.ready(0) and box.take(0) == {'clutch': 1.0, 'gear': 1.0}
    assert box.ready(1) and box.take(1) == {}
    box.offer('gear', LE + struct.pack('<b', 3))           # not what the scene plays at step 3
    with pytest.raises(CommandError, match='step 3 carried 3, the scene'):
        box.take(3)
    with pytest.raises(CommandError):
        box.offer('clutch', LE + struct.pack('<d', 2.0))
    assert box.refused['clutch'] == 1 and box.received['clutch'] == 1


def test_inbox_without_a_plan_keeps_the_latest_value_until_taken() -> None:
    box = CommandInbox(None)
    assert box.ready(0) and box.take(0) == {}
    box.offer('brake', LE + struct.pack('<d', 0.2))
    box.offer('brake', LE + struct.pack('<d', 0.4))
    assert box.take(7) == {'brake': 0.4} and box.take(8) == {}


def test_random_bytes_decode_or_raise_command_error_only() -> None:
    """2000 seeded byte strings (0..40 bytes, half of them with a valid CDR header): every
    decoder returns a number or raises CommandError, never anything else."""
    import random
    rng = random.Random(6)
    for _ in range(2000):
        n = rng.randrange(0, 41)
        data = bytes(rng.randrange(256) for _ in range(n))
        if rng.random() < 0.5 and n >= 4:
            data = rng.choice((LE, BE)) + data[4:]
        for channel in ('clutch', 'gear'):
            try:
                value = decode_command(channel, data)
            except CommandError:
                continue
            assert isinstance(value, float)
        try:
            decode_clock_ns(data)
        except CommandError:
            pass
