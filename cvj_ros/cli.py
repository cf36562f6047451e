"""`cvj-sim`: command-line entry point.

Subcommands live in :mod:`cvj_ros.commands` (one module each). A user error
(:class:`cvj_ros.errors.CvjError`) prints one line ``cvj-sim: error: <field>: <problem>``
to stderr and exits with status 2; no traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from cvj_ros.commands import COMMANDS
from cvj_ros.errors import CvjError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='cvj-sim',
        description='cvj_ros virtual driveline: kinematics, offline simulation, ROS runs, '
                    'bag replay and analysis, benchmark.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f'cvj_ros.commands.{name}')
        except ModuleNotFoundError as exc:
            if exc.name != f'cvj_ros.commands.{name}':
                raise
            continue  # subcommand not built yet
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, 'DESCRIPTION', mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except CvjError as exc:
        print(f'cvj-sim: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('cvj-sim: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
