"""Measured data for a fit: shipped tables, CSV ordinates and time series, bad files."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cvj_ros.fit.data import FitDataError, read_measured
from cvj_ros.measurements import load_table
from cvj_ros.physics.ordinates import ordinate_harmonics


def test_shipped_table_is_its_cycle_mean_harmonics():
    m = read_measured('davidbaev2023/4.3', orders=5)
    h = ordinate_harmonics(load_table('4.3').ordinates.mean(axis=0))
    assert m.kind == 'ordinates' and m.mean == h.mean
    np.testing.assert_array_equal(m.amplitudes, h.amplitudes[:5])


def test_ordinate_csv_with_two_revolutions(tmp_path):
    phi = 2 * math.pi * np.arange(12) / 12
    rev1 = 200 + 30 * np.cos(phi) + 5 * np.sin(2 * phi)
    rev2 = 200 + 30 * np.cos(phi) + 5 * np.sin(2 * phi) + 2.0
    p = tmp_path / 'ord.csv'
    p.write_text('angle_deg,torque_1,torque_2\n' + ''.join(
        f'{30 * i},{float(a)!r},{float(b)!r}\n' for i, (a, b) in enumerate(zip(rev1, rev2))))
    m = read_measured(str(p), orders=3)
    assert m.mean == pytest.approx(201.0)
    np.testing.assert_allclose(m.amplitudes, [30, 5, 0], atol=1e-9)


def test_time_series_from_speed(tmp_path):
    t = np.linspace(0, 2, 4001)
    w = 40.0
    phi = w * t
    torque = 150 + 10 * np.cos(2 * phi + 0.3)
    p = tmp_path / 'ts.csv'
    np.savetxt(p, np.column_stack([t, np.full_like(t, w), torque]), delimiter=',',
               header='t_s,speed_rad_s,torque_Nm', comments='')
    m = read_measured(str(p), orders=3, skip=0.1)
    assert m.kind == 'series'
    # linear interpolation of samples 0.02 rad apart onto the angle grid: an order-2 error
    # of at most A (2 * 0.02)^2 / 8 = 2e-3 N m
    np.testing.assert_allclose(m.amplitudes, [0, 10, 0], atol=2e-3)
    assert m.mean == pytest.approx(150, abs=1e-3)


@pytest.mark.parametrize('text, msg', [
    ('angle_deg,torque\n0,1\n90,2\n180,x\n270,1\n', 'line 4, column torque: not a number'),
    ('angle_deg,torque\n0,1\n100,2\n180,1\n270,1\n', 'column angle_deg'),
    ('angle_deg,other\n0,1\n90,2\n', 'torque columns'),
    ('t_s,torque_Nm\n0,1\n1,2\n', 'angle_rad or speed_rad_s'),
    ('a,b\n1\n2,3\n', 'line 2: 1 fields'),
    ('t_s,torque_Nm,angle_rad\n0,1,0\n1,nan,1\n', 'not finite'),
])
def test_bad_csv_names_file_and_field(tmp_path, text, msg):
    p = tmp_path / 'bad.csv'
    p.write_text(text)
    with pytest.raises(FitDataError, match=msg):
        read_measured(str(p), orders=1)


def test_missing_data_and_table():
    with pytest.raises(FitDataError, match='no such file'):
        read_measured('/nonexistent/x.csv', orders=2)
    with pytest.raises(FitDataError, match='no such shipped table'):
        read_measured('davidbaev2023/4.12', orders=2)
    with pytest.raises(FitDataError, match='--orders'):
        read_measured('davidbaev2023/4.2', orders=6)


def test_bag_of_a_simulation(tmp_path):
    from cvj_ros.cli import main
    bag = tmp_path / 'bag'
    assert main(['simulate', 'kavz685_lever', '--duration', '1.0', '--bag', str(bag)]) == 0
    m = read_measured(str(bag), orders=2, shaft='drive_shaft', skip=0.3)
    assert m.kind == 'series' and m.shaft == 'drive_shaft'
    # the drive shaft passes on the mean load (107.5 N m, +-8.8 N m random) in steady state
    assert m.mean == pytest.approx(107.5, abs=5.0)
    with pytest.raises(FitDataError, match='--shaft nosuch'):
        read_measured(str(bag), orders=2, shaft='nosuch')


def test_standard_error_from_the_revolutions():
    # two revolutions differing by a constant 2 N m: the mean's standard error is
    # std([a, a + 2], ddof=1)/sqrt(2) = 1, and no order scatters
    phi = 2 * math.pi * np.arange(12) / 12
    rev = 200 + 30 * np.cos(phi)
    from cvj_ros.fit.data import _from_ordinates
    m = _from_ordinates('x', np.array([rev, rev + 2.0]), 2, shaft=None, angle_shaft=None)
    np.testing.assert_allclose(m.stderr, [1.0, 0.0, 0.0], atol=1e-12)
    # one order-1 coefficient scattering by +-d between two revolutions
    d = 3.0
    m = _from_ordinates('x', np.array([rev + d * np.cos(phi), rev - d * np.cos(phi)]), 2,
                        shaft=None, angle_shaft=None)
    # sum |c_i - c|^2 = 2 d^2 over N (N - 1) = 2: standard error d
    np.testing.assert_allclose(m.stderr, [0.0, d, 0.0], atol=1e-12)
    assert read_measured('davidbaev2023/4.3', orders=4).stderr.shape == (5,)
