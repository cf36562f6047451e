"""`cvj-sim kinematics`: CSV output, table and summary, registry-driven help and params,
user errors as one line with exit status 2."""
from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest

from cvj_ros.cli import main
from cvj_ros.physics.joints import JOINTS, make_joint


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(['kinematics', *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_csv_parses_with_header_and_rows(capsys) -> None:
    code, out, err = run_cli(capsys, 'hooke', '--beta', '30', '--samples', '37', '--revolutions', '3', '--csv')
    assert code == 0 and err == ''
    rows = list(csv.reader(io.StringIO(out)))
    assert rows[0] == ['phi_in', 'phi_out', 'ratio', 'ratio_slope']
    data = np.array(rows[1:], dtype=float)
    assert data.shape == (37, 4)
    assert data[0, 0] == 0.0 and data[-1, 0] == pytest.approx(6 * math.pi)   # radians
    ev = make_joint('hooke', beta=math.radians(30)).evaluate(data[:, 0])
    assert np.array_equal(data[:, 1], ev.phi_out) and np.array_equal(data[:, 2], ev.ratio)


def test_csv_phi_mid_column_for_rzeppa(capsys) -> None:
    code, out, _ = run_cli(capsys, 'rzeppa', '--delta', '40', '--alpha', '12', '--samples', '9', '--csv')
    rows = list(csv.reader(io.StringIO(out)))
    assert code == 0 and rows[0] == ['phi_in', 'phi_out', 'ratio', 'ratio_slope', 'phi_mid'] and len(rows) == 10
    data = np.array(rows[1:], dtype=float)
    k = math.tan(math.radians(12)) * math.sin(math.radians(40)) + math.cos(math.radians(40))
    assert data[0, 2] == pytest.approx(1 / k)        # ratio at phi = 0 from seed 003 eq. 10


def test_table_and_summary(capsys) -> None:
    code, out, _ = run_cli(capsys, 'double_cardan', '--beta', '20', '--beta2', '30', '--samples', '5')
    lines = out.strip().splitlines()
    assert code == 0 and lines[1].split()[0] == 'phi_in[deg]' and len(lines) == 1 + 1 + 5 + 1
    summary = lines[-1]
    assert 'ratio min' in summary and 'angle deviation over a revolution' in summary
    assert 'speed nonuniformity (max-min)/mean of the ratio' in summary
    c = math.cos(math.radians(20)) / math.cos(math.radians(30))
    assert f'{math.atan(abs(1 - c) / (2 * math.sqrt(c))):.6g}' in summary


def test_generic_param_and_degrees(capsys) -> None:
    code, out, _ = run_cli(capsys, 'double_cardan', '--param', 'beta1_deg=25', '--param', 'beta2=0.4363323129985824',
                           '--param', 'layout=W', '--samples', '4', '--csv')
    assert code == 0
    data = np.array(list(csv.reader(io.StringIO(out)))[1:], dtype=float)
    assert np.abs(data[:, 1] - data[:, 0]).max() < 1e-12      # 25 deg both: homokinetic
    assert code == 0


@pytest.mark.skipif('tripod' not in JOINTS, reason='tripod joint (part B) not built')
def test_joint_written_by_others_via_registry(capsys) -> None:
    code, out, _ = run_cli(capsys, 'tripod', '--beta', '20', '--r', '0.026', '--l', '0.7', '--model', 'closed',
                           '--samples', '6', '--csv')
    assert code == 0 and len(out.strip().splitlines()) == 7


def test_help_lists_joints_and_parameters(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(['kinematics', '--help'])
    out = capsys.readouterr().out
    assert info.value.code == 0
    for kind in ('hooke', 'double_cardan', 'rzeppa', 'gear', 'chain', 'ideal_cv'):
        assert kind in out
    assert 'beta2' in out and 'alpha' in out and '--param' in out


@pytest.mark.parametrize('argv,field', [
    (['hooke', '--beta', '90'], 'beta'),
    (['hooke', '--beta', '120'], 'beta'),
    (['hooke', '--beta', 'nan'], 'beta'),
    (['double_cardan', '--beta', '10', '--beta2', '95'], 'beta2'),
    (['rzeppa', '--delta', '-3'], 'delta'),
    (['hooke', '--beta', '10', '--model', 'closed'], 'model'),
    (['hooke', '--beta', '10', '--model', 'best'], 'model'),
    (['cardan', '--beta', '10'], 'JOINT'),
    (['hooke', '--param', 'gamma=1'], 'gamma'),
    (['hooke', '--alpha', '3'], 'alpha'),
    (['hooke', '--samples', '1'], 'samples'),
])
def test_user_errors_one_line_exit_2(capsys, argv, field) -> None:
    code, out, err = run_cli(capsys, *argv)
    assert code == 2 and out == ''
    assert err.count('\n') == 1 and err.startswith(f'cvj-sim: error: {field}: ')
