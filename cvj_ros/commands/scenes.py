"""`cvj-sim scenes`: list the shipped scenes (config/scenes, or the ament share dir)."""
from __future__ import annotations

import argparse

NAME = 'scenes'
HELP = 'list shipped scenes with one-line descriptions'
DESCRIPTION = """List the scene files shipped with cvj_ros (config/scenes in the source tree,
share/cvj_ros/config/scenes when installed). Any command taking SCENE accepts a shipped
name (kavz685_lever) or a path.

examples:
  cvj-sim scenes
  cvj-sim scenes --paths
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--paths', action='store_true', help='print each scene file path too')


def run(args: argparse.Namespace) -> int:
    from cvj_ros.errors import CvjError
    from cvj_ros.physics.scene import load_scene, shipped_scenes
    scenes = shipped_scenes()
    if not scenes:
        print('no shipped scenes found')
        return 1
    width = max(len(n) for n in scenes)
    for name, path in scenes.items():
        try:
            desc = load_scene(path).description
        except CvjError as exc:
            desc = f'(invalid: {exc})'
        line = f'{name:<{width}}  {desc}'
        print(line + (f'  [{path}]' if args.paths else ''))
    return 0
