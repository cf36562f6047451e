"""Project errors.

Every error a user can cause derives from :class:`CvjError`; the CLI prints
``str(err)`` as one line and exits non-zero, never a traceback. Messages start with
the offending field or parameter: ``"joints[1].beta_deg: must be < 90, got 95"``.
"""
from __future__ import annotations


def not_a_number(value: object) -> str:
    """The message for a value that must be a number: ``must be a number, got X``; when X is
    text that reads as a finite number (``1e6``, ``1.0e300``), it says why: YAML 1.1, which
    PyYAML implements, reads a number with an exponent as a float only with a dot in the
    mantissa and a sign in the exponent (``1.0e+6``); YAML 1.2 (and most editors) would
    take it as a number."""
    if isinstance(value, str):
        try:
            v = float(value.strip().replace('_', ''))
        except ValueError:
            v = float('nan')
        if 'e' in value.lower() and v == v and abs(v) != float('inf'):
            digits = next(d for d in range(17) if float(f'{v:.{d}e}') == v)
            mant, _, exp = f'{v:.{digits}e}'.partition('e')
            fixed = f'{mant if "." in mant else mant + ".0"}e{exp}'
            return (f'must be a number, got the text {value!r} (YAML 1.1, as read here, takes a '
                    f'number with an exponent only with a dot and a signed exponent: write {fixed})')
    return f'must be a number, got {value!r}'


class CvjError(Exception):
    """Base class of all user-facing cvj_ros errors."""


class GeometryError(CvjError, ValueError):
    """Invalid joint geometry (beta >= 90 deg for Hooke, r >= l for a tripod, NaN ...).

    Attributes:
        parameter: name of the offending parameter (e.g. ``"beta"``).
    """

    def __init__(self, parameter: str, message: str) -> None:
        self.parameter = parameter
        super().__init__(f'{parameter}: {message}')


class SceneError(CvjError, ValueError):
    """Invalid scene file or scene field.

    Attributes:
        field: dotted path of the offending field (e.g. ``"elements[2].stiffness"``).
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(f'{field}: {message}')


class SolverError(CvjError, RuntimeError):
    """Integration failed (step size underflow, non-finite state)."""


class BagError(CvjError):
    """A bag is missing, unreadable or lacks a needed topic."""


class LockstepError(CvjError, RuntimeError):
    """The lockstep loop cannot continue (peer timeout, bad stamp, non-finite torque)."""


class StartCancelled(Exception):
    """A node told to wait for a start signal (coupling_node ``start_gate``) did not get it:
    not an error of the node, which exits 0 without starting (so not a CvjError)."""
