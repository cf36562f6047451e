"""The one line `cvj-sim run` shows for a node that stopped: :func:`error_line` of its log."""
from __future__ import annotations

from pathlib import Path

from cvj_ros.orchestrate.processes import error_line


def test_error_line_takes_off_rclpys_prefix(tmp_path: Path) -> None:
    log = tmp_path / 'coupling_node.log'
    log.write_text('[INFO] [1795891540.1] [coupling_node]: waiting for peers\n'
                   '[ERROR] [1795891544.977407028] [coupling_node]: free-run: /engine/wrench has 2 '
                   'publishers (expected 1)\n'
                   '[INFO] [1795891545.0] [coupling_node]: bye\n')
    assert error_line(log) == 'free-run: /engine/wrench has 2 publishers (expected 1)'


def test_error_line_keeps_program_lines_and_falls_back(tmp_path: Path) -> None:
    log = tmp_path / 'engine_node.log'
    log.write_text('engine_node: error: m1: must be finite, got nan\n')
    assert error_line(log) == 'engine_node: error: m1: must be finite, got nan'
    log.write_text('[FATAL] [12.5] [/ns/engine_node]: out of memory\n')
    assert error_line(log) == 'out of memory'
    log.write_text('Traceback (most recent call last):\n  ...\nValueError: x\n\n')
    assert error_line(log) == 'ValueError: x'
    assert error_line(tmp_path / 'missing.log') is None
