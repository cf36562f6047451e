"""ament_python package definition for cvj_ros.

`colcon build` installs the node executables to ``lib/cvj_ros`` (setup.cfg), which is
where ``ros2 run cvj_ros <node>`` looks them up through the ament index. A plain
``pip install`` puts the same executables on the venv's PATH.

The executables are not pip console scripts but POSIX-sh launchers written here
(:func:`launcher_text`): they start this Python with SIGINT blocked, so a Ctrl-C during the
interpreter's own start-up waits for ``cvj_ros.start.run``, which ends the program quietly
(docs/ros.md "Packaging").
"""
import shlex
import sys
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'cvj_ros'

NODES = ['engine_node', 'coupling_node', 'load_node', 'monitor_node', 'replay_node', 'driver_node']

# executable -> the function it runs; each node's main() through its launcher
# (cvj_ros/nodes/entry.py: a Ctrl-C during the node module's imports ends it quietly)
EXECUTABLES = {'cvj-sim': 'cvj_ros.cli:main', 'driveline_composed': 'cvj_ros.composed:main',
               **{n: f'cvj_ros.nodes.entry:{n}' for n in NODES}}
LAUNCHER_DIR = Path('build') / 'cvj_launchers'


def launcher_text(target: str, python: str, block: bool = True) -> str:
    """The launcher of ``target`` ('module:function'): ``python`` started by GNU env with
    SIGINT blocked (a blocked signal stays pending across exec), ``-P`` (no script or working
    directory on sys.path), running ``cvj_ros.start.run(target)`` with the launcher's path
    as ``sys.argv[0]``. ``block=False`` (an ``env`` without ``--block-signal``): Python
    directly, as a console script would start it."""
    code = f'from cvj_ros.start import run; run("{target}")'
    env = '/usr/bin/env --block-signal=INT ' if block else ''
    return ('#!/bin/sh\n'
            '# cvj_ros executable (written by setup.py): Python starts with SIGINT blocked and\n'
            '# cvj_ros.start takes it over, so a Ctrl-C during start-up prints no traceback\n'
            f'exec {env}{shlex.quote(python)} -P -c {shlex.quote(code)} "$0" "$@"\n')


def env_blocks_signals() -> bool:
    """``/usr/bin/env --block-signal`` works here (GNU coreutils 8.31 or newer)."""
    import subprocess
    try:
        return subprocess.run(['/usr/bin/env', '--block-signal=INT', 'true'], timeout=30,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def write_launchers() -> list[str]:
    """Write every executable's launcher for the Python running this build (as pip's
    console scripts name it in their first line); their paths, relative to setup.py."""
    here = Path(__file__).resolve().parent
    (here / LAUNCHER_DIR).mkdir(parents=True, exist_ok=True)
    paths = []
    block = env_blocks_signals()
    if not block:
        print('cvj_ros: /usr/bin/env has no --block-signal (GNU coreutils < 8.31): the executables '
              'start Python directly; a Ctrl-C during its start-up can print a traceback',
              file=sys.stderr)
    for name, target in EXECUTABLES.items():
        path = here / LAUNCHER_DIR / name
        text = launcher_text(target, sys.executable, block)
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
        path.chmod(0o755)
        paths.append(str(LAUNCHER_DIR / name))
    return paths


setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the measured tables (cvj_ros.measurements) ship inside the package
    package_data={package_name: ['data/davidbaev2023/*.csv', 'data/davidbaev2023/*.md']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config/scenes', glob('config/scenes/*.yaml')),
        ('share/' + package_name + '/config/params', glob('config/params/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/examples', glob('examples/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='cvj_ros developers',
    maintainer_email='cvj-ros@example.org',
    description='Virtual driveline for ROS 2 with exact coupling kinematics.',
    license='Apache-2.0',
    tests_require=['pytest'],
    scripts=write_launchers(),
)
