"""`cvj-sim` subcommands: one module per subcommand.

Each module defines ``NAME`` (str), ``HELP`` (str), ``add_arguments(parser)`` and
``run(args) -> int``. :mod:`cvj_ros.cli` discovers them from ``COMMANDS``.
"""

COMMANDS = ('kinematics', 'scenes', 'simulate', 'run', 'record', 'replay', 'analyze', 'reindex',
            'bench', 'sweep', 'fit')
