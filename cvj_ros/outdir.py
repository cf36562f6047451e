"""An output directory given on the command line is checked before any work starts.

``cvj-sim run|record|sweep|bench`` write into ``--out DIR`` (``record``: ``OUT``); a
directory that cannot be created or written (``/proc/foo``, a file in the way, no
permission) ends the command at once with one line naming the option, instead of an
unexpected error blamed on the scene after the work. The check creates the missing
directories and removes what it created, so nothing is left behind.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from cvj_ros.errors import CvjError

__all__ = ['check_out_dir']


def check_out_dir(path: str | os.PathLike[str], option: str = '--out') -> None:
    """Raise CvjError naming ``option`` when ``path`` cannot be a writable directory."""
    p = Path(path)
    created: list[Path] = []
    try:
        missing = [d for d in (p, *p.parents) if not d.exists()]
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
        if not p.is_dir():
            raise CvjError(f'{option}: {p} exists and is not a directory')
        with tempfile.TemporaryFile(dir=p):
            pass
    except OSError as exc:
        raise CvjError(f'{option}: cannot write to {p}: {exc.strerror or exc}') from None
    finally:
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                pass
