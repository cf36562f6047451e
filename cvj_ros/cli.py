"""`cvj-sim`: command-line entry point.

Subcommands live in :mod:`cvj_ros.commands` (one module each). A user error
(:class:`cvj_ros.errors.CvjError`) prints one line ``cvj-sim: error: <field>: <problem>``
to stderr and exits with status 2; anything unexpected prints one line naming the file or
bag being read and exits 1 (:mod:`cvj_ros.guard`); the traceback only with ``--debug``
(before the subcommand) or ``CVJ_DEBUG=1``. ROS arguments (``--ros-args ... [--]``, as
launch_ros appends them to every command it starts) are accepted and ignored
(:mod:`cvj_ros.rosargs`).

Only the subcommand named on the command line is imported (all of them for ``--help``
or a name that is not a subcommand), so ``cvj-sim simulate`` does not pay for the
imports of the others (docs/solvers.md "Start-up"). Run as the program (``argv`` None:
the console script, ``python -m cvj_ros.cli``), a subcommand that sets
``EXIT_WITHOUT_TEARDOWN = True`` ends the process with :func:`exit_without_teardown`.

A Ctrl-C at any point of :func:`main` (also while it imports the subcommand) prints
``cvj-sim: interrupted`` and exits 130. This module imports next to nothing at load time
(``argparse`` and the rest inside the functions), so the window before ``main`` runs is
short; the installed ``cvj-sim`` (setup.py's launcher, :mod:`cvj_ros.start`) starts Python
with SIGINT blocked until then, so a Ctrl-C during Python's own start-up ends it the same way.
"""
from __future__ import annotations

import os
import sys
from collections.abc import Sequence   # loaded by Python's start-up already (os)

from cvj_ros.commands import COMMANDS

# (annotations name argparse types; ``from __future__ import annotations`` never evaluates them)


def command_named(argv: Sequence[str]) -> str | None:
    """The subcommand that ``argv`` (without the program name) names, if it names one:
    its first token that is not ``--debug``; None for ``-h``/``--help``, an unknown name
    or no name at all."""
    for token in argv:
        if token == '--debug':
            continue
        return token if token in COMMANDS else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``cvj-sim`` parser with every subcommand, or with the subcommand ``only``
    alone (its module is then the only one imported)."""
    import argparse
    import importlib
    parser = argparse.ArgumentParser(
        prog='cvj-sim',
        description='cvj_ros virtual driveline: kinematics, offline simulation, ROS runs, '
                    'bag recording, replay and analysis, parameter sweeps, fits to '
                    'measurements, benchmark.')
    parser.add_argument('--debug', action='store_true',
                        help='print the traceback of an error (also: CVJ_DEBUG=1)')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    sub.required = True
    for name in (only,) if only is not None else COMMANDS:
        try:
            mod = importlib.import_module(f'cvj_ros.commands.{name}')
        except ModuleNotFoundError as exc:
            if exc.name != f'cvj_ros.commands.{name}':
                raise
            continue  # subcommand not built yet
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, 'DESCRIPTION', mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run,
                       _exit_without_teardown=getattr(mod, 'EXIT_WITHOUT_TEARDOWN', False))
    return parser


def exit_without_teardown(status: int) -> None:
    """End the process now with ``status``, as ``sys.exit(status)`` would but without the
    interpreter's teardown: atexit handlers run and stdout/stderr are flushed, then
    ``os._exit``. The teardown frees numba's and LLVM's object graphs one by one: measured
    0.15-0.2 s CPU of a ~1 s warm ``cvj-sim simulate``. Only for a command whose files are
    all closed when it returns, and only with no other thread alive (else it returns and the
    caller exits normally). A stdout closed early (``| head``) gives 141 like the guard."""
    import threading
    if threading.active_count() > 1:
        return
    import atexit
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BrokenPipeError:
            status = 141   # guard.EXIT_BROKEN_PIPE: reader gone, nothing to say
        except (OSError, ValueError):
            pass
    os._exit(status)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:
        pass
    except Exception as exc:   # a SIGINT inside an import's C extension surfaces as its cause
        from cvj_ros.guard import caused_by_sigint
        if not caused_by_sigint(exc):
            raise
    print('cvj-sim: interrupted', file=sys.stderr)
    return 130


def _main(argv: Sequence[str] | None) -> int:
    from cvj_ros.guard import guarded, reading
    from cvj_ros.rosargs import remove_ros_args
    as_program = argv is None
    if argv is None:
        argv = sys.argv[1:]
    argv = remove_ros_args(argv)
    # a cold physics kernel compiles on first use: say so while it does (this process and
    # the node processes a run starts; cvj_ros.physics.kernel.compiling)
    if as_program:
        os.environ.setdefault('CVJ_COMPILE_NOTICE', '1')
    parser = build_parser(command_named(argv))
    args = parser.parse_args(argv)
    # what the user handed in, for the error line of an unexpected exception
    label = getattr(args, 'scene', None) or getattr(args, 'bag', None) or args.command
    try:
        if getattr(args, 'out', None):   # an unusable output directory: one line naming it
            from cvj_ros.outdir import check_out_dir
            bad = guarded('cvj-sim', check_out_dir, args.out,
                          'OUT' if args.command == 'record' else '--out', debug=args.debug)
            if bad is not None:
                return int(bad)
        with reading(str(label)):
            status = int(guarded('cvj-sim', args._run, args, debug=args.debug) or 0)
    except KeyboardInterrupt:
        print('cvj-sim: interrupted', file=sys.stderr)
        return 130
    if as_program and args._exit_without_teardown:
        exit_without_teardown(status)
    return status


if __name__ == '__main__':
    sys.exit(main())
