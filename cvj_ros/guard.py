"""Top-level guard of every cvj_ros entry point: no user input reaches a traceback.

:func:`guarded` runs an entry point and turns anything it raises into one line on stderr
and a non-zero exit status:

* :class:`~cvj_ros.errors.CvjError` (a user error the code names):
  ``<prog>: error: <field or file>: <problem>``, exit 2 (:data:`EXIT_USER`);
* anything else (a case no check foresaw): ``<prog>: error: <what was being read>:
  <ExceptionType>: <message> (unexpected; run with --debug or CVJ_DEBUG=1 for the
  traceback)``, exit 1 (:data:`EXIT_UNEXPECTED`). ``<what was being read>`` is the innermost
  :func:`reading` context (a scene file, a bag, a parameter), else the program's own name;
* a broken stdout pipe (``cvj-sim ... | head``): silent, exit 141 (128 + SIGPIPE).

KeyboardInterrupt and SystemExit pass through unchanged (also an exception a KeyboardInterrupt
caused, e.g. a SIGINT inside a C extension's import: raised as KeyboardInterrupt), so the entry points keep their own
exit codes for Ctrl-C / SIGTERM (130 / 143 in ``cvj-sim run``, 0 in the nodes) and argparse's
usage errors (2). The traceback is printed (before the line) with ``--debug`` or when the
environment has ``CVJ_DEBUG=1``.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import traceback
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from cvj_ros.errors import CvjError

EXIT_UNEXPECTED = 1
EXIT_USER = 2
EXIT_BROKEN_PIPE = 141

_READING: contextvars.ContextVar[tuple[str, ...]] = contextvars.ContextVar('cvj_reading', default=())

T = TypeVar('T')


def debug_enabled(flag: bool = False) -> bool:
    """``--debug`` given, or ``CVJ_DEBUG`` set to anything but '', '0', 'no', 'false'."""
    return flag or os.environ.get('CVJ_DEBUG', '').strip().lower() not in ('', '0', 'no', 'false')


@contextlib.contextmanager
def reading(label: str) -> Iterator[None]:
    """Name what is being read (``'DIR/scene.yaml'``, ``'--load-from-bag: DIR/bag'``) for the
    error line of an unexpected exception raised inside the block (innermost label wins)."""
    token = _READING.set(_READING.get() + (str(label),))
    try:
        yield
    except Exception as exc:
        if not getattr(exc, '_cvj_reading', None):
            with contextlib.suppress(AttributeError, TypeError):
                exc._cvj_reading = _READING.get()   # type: ignore[attr-defined]
        raise
    finally:
        _READING.reset(token)


def describe_unexpected(exc: BaseException, prog: str) -> str:
    """The one error line for an unexpected exception (without the ``<prog>: error: `` head)."""
    where = getattr(exc, '_cvj_reading', None) or _READING.get()
    label = where[-1] if where else prog
    text = ' '.join(str(exc).split()) or repr(exc)
    if len(text) > 300:
        text = text[:297] + '...'
    return (f'{label}: {type(exc).__name__}: {text} (unexpected; run with --debug or '
            f'CVJ_DEBUG=1 for the traceback)')


def caused_by_sigint(exc: BaseException | None) -> bool:
    """``exc`` is a KeyboardInterrupt or was raised because of one (its ``__cause__`` /
    ``__context__`` chain holds one): a SIGINT inside a C extension's initialisation
    (rclpy's ``_rclpy_pybind11``) surfaces as ``ImportError: initialization failed`` caused
    by the KeyboardInterrupt."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def guarded(prog: str, entry: Callable[..., T], *args: Any, debug: bool = False,
            **kwargs: Any) -> T | int:
    """``entry(*args, **kwargs)``, or an exit status after one error line (see module doc)."""
    def trace(exc: BaseException) -> None:
        if debug_enabled(debug):
            traceback.print_exception(exc, file=sys.stderr)

    try:
        return entry(*args, **kwargs)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except CvjError as exc:
        trace(exc)
        print(f'{prog}: error: {" ".join(str(exc).split())}', file=sys.stderr)   # one line
        return EXIT_USER
    except Exception as exc:  # noqa: BLE001  (the point of the guard)
        if caused_by_sigint(exc):   # Ctrl-C inside an import or a C call: the caller's Ctrl-C path
            raise KeyboardInterrupt from exc
        trace(exc)
        print(f'{prog}: error: {describe_unexpected(exc, prog)}', file=sys.stderr)
        return EXIT_UNEXPECTED


def _silence_stdout() -> None:
    """After EPIPE: point stdout at /dev/null so the interpreter's final flush does not fail."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass
