"""cvj_ros/physics never imports ROS: every module of the package imports in a fresh
interpreter whose import system refuses ROS packages (rclpy, rosbags, the message packages,
the project's node and bag modules), and no source line of the package names one (a static
check that also sees imports inside functions, which the import test only runs if called)."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import cvj_ros.physics

#: top-level packages of a ROS 2 install or of the bag library, and the project's modules
#: built on them (cvj_ros.nodes uses rclpy, cvj_ros.bag rosbags)
BANNED = ('rclpy', 'rosbags', 'rosidl_runtime_py', 'rosidl_parser', 'rpyutils', 'rmw', 'rcl_interfaces',
          'builtin_interfaces', 'std_msgs', 'sensor_msgs', 'geometry_msgs', 'diagnostic_msgs',
          'rosgraph_msgs', 'launch', 'launch_ros', 'ament_index_python', 'cvj_ros.nodes',
          'cvj_ros.bag', 'cvj_ros.orchestrate', 'cvj_ros.composed')

PACKAGE_DIR = Path(cvj_ros.physics.__file__).parent

_PROBE = r'''
import importlib, json, pkgutil, sys
BANNED = tuple(json.loads(sys.argv[1]))
tried = []

class Refuse:
    """Meta-path finder first in line: a banned name is recorded and refused."""
    def find_spec(self, name, path=None, target=None):
        if any(name == b or name.startswith(b + '.') for b in BANNED):
            tried.append((name, sys._getframe(1).f_globals.get('__name__', '?')))
            raise ImportError(f'ROS import refused: {name}')
        return None

sys.meta_path.insert(0, Refuse())
import cvj_ros.physics as pkg
failed, modules = [], []
for info in pkgutil.walk_packages(pkg.__path__, prefix='cvj_ros.physics.'):
    modules.append(info.name)
    try:
        importlib.import_module(info.name)
    except Exception as exc:          # noqa: BLE001 - reported with the module's name
        failed.append([info.name, f'{type(exc).__name__}: {exc}'])
loaded = sorted(m for m in sys.modules if any(m == b or m.startswith(b + '.') for b in BANNED))
print(json.dumps({'modules': modules, 'failed': failed, 'tried': tried, 'loaded': loaded}))
'''


def test_every_physics_module_imports_without_ros() -> None:
    out = subprocess.run([sys.executable, '-c', _PROBE, json.dumps(BANNED)], capture_output=True,
                         text=True, timeout=600, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got['tried'] == [] and got['loaded'] == [], got
    assert got['failed'] == [], got['failed']
    # the walk saw the whole package (every .py file below it is a module it imported)
    files = {'.'.join(('cvj_ros', 'physics', *p.relative_to(PACKAGE_DIR).with_suffix('').parts))
             for p in PACKAGE_DIR.rglob('*.py') if p.name != '__init__.py'}
    assert files <= set(got['modules']), sorted(files - set(got['modules']))


def test_the_hook_refuses_a_ros_import() -> None:
    """The probe's hook catches an import (the check above would pass vacuously without)."""
    probe = _PROBE.replace("import cvj_ros.physics as pkg",
                           "import cvj_ros.physics as pkg\ntry:\n    import rclpy\nexcept ImportError:\n    pass")
    out = subprocess.run([sys.executable, '-c', probe, json.dumps(BANNED)], capture_output=True,
                         text=True, timeout=600, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert [name for name, _by in got['tried']] == ['rclpy']


_IMPORT = re.compile(r'^\s*(?:from\s+([\w.]+)\s+import\s+([\w, ()]+)|import\s+([\w., ]+))', re.M)


def _imported(source: str) -> list[str]:
    names: list[str] = []
    for m in _IMPORT.finditer(source):
        if m.group(1):
            names.append(m.group(1))
            names += [f'{m.group(1)}.{n.strip()}' for n in m.group(2).strip('()').split(',') if n.strip()]
        else:
            names += [n.strip().split(' as ')[0] for n in m.group(3).split(',')]
    return names


def test_no_source_line_imports_ros() -> None:
    bad = []
    for path in sorted(PACKAGE_DIR.rglob('*.py')):
        for name in _imported(path.read_text(encoding='utf-8')):
            if any(name == b or name.startswith(b + '.') for b in BANNED):
                bad.append(f'{path.relative_to(PACKAGE_DIR.parent.parent)}: {name}')
    assert bad == []
    # the static scan finds what it looks for
    assert _imported('def f():\n    from cvj_ros import bag\n    import rclpy.node as n\n') == [
        'cvj_ros', 'cvj_ros.bag', 'rclpy.node']
