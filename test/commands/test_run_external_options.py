"""`cvj-sim run --external` option checks (prepare(): nothing is started) and the wait line."""
from __future__ import annotations

from pathlib import Path

import pytest

from cvj_ros.cli import main
from cvj_ros.errors import CvjError
from cvj_ros.orchestrate import RunOptions, external_wait_line, prepare


def test_external_peer_is_not_started(tmp_path: Path) -> None:
    assert 'load_node' not in prepare(RunOptions('kavz685_lever', tmp_path, external=('load',))).nodes
    both = prepare(RunOptions('kavz685_lever', tmp_path, external=('engine', 'load'))).nodes
    assert 'engine_node' not in both and 'load_node' not in both and 'coupling_node' in both


@pytest.mark.parametrize('options, message', [
    (dict(external=('wheel',)), "--external: must be engine, load, driver or a combination, got 'wheel'"),
    (dict(external=('load',), external_timeout=0.0), '--external-timeout: must be > 0, got 0.0'),
    (dict(external=('load',), load_from_bag=Path('x')), '--load-from-bag: cannot be combined with --external load'),
    (dict(nonfinite_torque='skip'), "--nonfinite-torque: must be stop or hold, got 'skip'"),
])
def test_bad_external_options_name_the_option(tmp_path: Path, options: dict, message: str) -> None:
    with pytest.raises(CvjError) as err:
        prepare(RunOptions('kavz685_lever', tmp_path, **options))
    assert str(err.value).startswith(message)


def test_cli_bad_external_timeout_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(['run', 'kavz685_lever', '--out', str(tmp_path), '--external', 'load',
                 '--external-timeout', '-1']) == 2
    err = capsys.readouterr().err
    assert err == 'cvj-sim: error: --external-timeout: must be > 0, got -1.0\n'


def test_wait_line_names_topic_domain_and_what_to_publish() -> None:
    line = external_wait_line(('engine', 'load'), 42, 30.0)
    assert line.startswith('cvj-sim run: waiting up to 30 s for an outside node on ROS_DOMAIN_ID=42 '
                           'to publish /engine/wrench (the engine torque')
    assert '/load/wrench (the resisting torque' in line and 'echoes the joint state' in line
    assert '\n' not in line


def test_external_driver_leaves_out_driver_node_and_needs_a_mode_scene(tmp_path: Path) -> None:
    assert 'driver_node' in prepare(RunOptions('launch_clutch_chain', tmp_path)).nodes
    prep = prepare(RunOptions('launch_clutch_chain', tmp_path, external=('driver', 'load')))
    assert 'driver_node' not in prep.nodes and 'load_node' not in prep.nodes
    from cvj_ros.orchestrate.processes import node_parameters
    assert node_parameters(prep, 'coupling_node', load_override=None)['commands'] == 'external'
    assert node_parameters(prep, 'coupling_node', load_override=None)['mode_backend'] == 'auto'
    prep = prepare(RunOptions('launch_clutch_chain', tmp_path, mode_backend='python'))
    assert node_parameters(prep, 'coupling_node', load_override=None)['mode_backend'] == 'python'
    # the engine node counts the driver's throttle samples in lockstep
    assert node_parameters(prep, 'engine_node', load_override=None)['commands'] == 'driver'
    with pytest.raises(CvjError, match='^--mode-backend: must be auto, kernel or python'):
        prepare(RunOptions('launch_clutch_chain', tmp_path, mode_backend='fast'))
    with pytest.raises(CvjError, match='^--external driver: kavz685_lever.yaml has no clutch'):
        prepare(RunOptions('kavz685_lever', tmp_path, external=('driver',)))
    line = external_wait_line(('driver', 'load'), 7, 30.0)
    assert '/load/wrench' in line and '/driveline/clutch' in line


def test_cli_external_repeats_and_expands_both(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = {}
    import cvj_ros.orchestrate as orch
    from types import SimpleNamespace

    def fake_run(options, **kw):
        seen['o'] = options
        return SimpleNamespace(error=None, exit_code=0, metrics={}, scene_path=None)
    monkeypatch.setattr(orch, 'run', fake_run)
    assert main(['run', 'launch_clutch_chain', '--out', str(tmp_path), '--external', 'driver',
                 '--external', 'both']) == 0
    assert seen['o'].external == ('driver', 'engine', 'load')
