"""Compiled physics core (issue 9): scene as data, numba kernels, compiled steppers.

Importing this package does not import numba; ``steppers_nb`` (and core-A's
``rhs_nb``) do. Before that, :func:`configure_cache` points numba's on-disk cache
at a writable place: numba's default (``__pycache__`` next to the sources) when
the install is writable, else a user cache directory, so read-only site-packages
and colcon install trees work. ``NUMBA_CACHE_DIR`` set by the user always wins.
"""
from __future__ import annotations

import os


def choose_cache_dir(package_dir: str, env: dict, writable) -> str | None:
    """Numba cache directory to use: None = numba's default (next to the sources).

    package_dir: this package's directory; env: the environment mapping;
    writable(path) -> bool. User cache: $XDG_CACHE_HOME/cvj_ros/numba, else
    ~/.cache/cvj_ros/numba (HOME from env)."""
    if env.get('NUMBA_CACHE_DIR'):
        return env['NUMBA_CACHE_DIR']
    pycache = os.path.join(package_dir, '__pycache__')
    if writable(pycache if os.path.isdir(pycache) else package_dir):
        return None
    base = env.get('XDG_CACHE_HOME') or os.path.join(env.get('HOME', os.path.expanduser('~')),
                                                     '.cache')
    return os.path.join(base, 'cvj_ros', 'numba')


def configure_cache() -> None:
    """Set NUMBA_CACHE_DIR before numba is imported when the install is read-only."""
    path = choose_cache_dir(os.path.dirname(os.path.abspath(__file__)), os.environ,
                            lambda p: os.access(p, os.W_OK))
    if path is not None and not os.environ.get('NUMBA_CACHE_DIR'):
        os.environ['NUMBA_CACHE_DIR'] = path


configure_cache()
