"""Run identity: the per-run token carried in ``header.frame_id`` (issue 10 item 4).

Two runs on one ROS domain publish on the same topics with the same stamps (t_k = k * h),
so a stamp alone cannot tell whose message it is. Every run started by ``cvj-sim run`` gets
a random token (:func:`new_run_token`, 8 lowercase hex characters, 32 bits) that the nodes
get as the ``run_token`` parameter. A run-tagged ``header.frame_id`` is
``<frame>@<token>``: the token is the text after the LAST ``@``
(:func:`frame_token`).

* coupling_node publishes /driveline/joint_states with frame_id ``driveline@<token>``,
  the reaction wrenches with ``<joint>_housing@<token>`` and /diagnostics with
  ``coupling_node@<token>``; it puts ``run_token`` in /driveline/scene.
* An answer on /engine/wrench or /load/wrench must carry the joint state's token: copying
  the joint state's whole header (stamp and frame_id) does it; engine_node and load_node
  write ``<shaft>@<token>``. An answer with another token is ignored and counted
  (``foreign_answers``); an answer without any ``@`` is accepted as before (an outside node
  that echoes only the stamp), counted as ``untokened_answers``.
* The recorder and monitor_node drop messages whose frame_id carries another token.

An empty ``run_token`` (the default under ``ros2 run``) tags nothing and accepts all.

/clock (rosgraph_msgs/Clock) has no header and cannot carry a token: the recorder writes a
/clock sample only while exactly one /clock publisher is matched (its run's coupling node),
see :class:`cvj_ros.bag.BagRecorder`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cvj_ros.nodes.parameters import ParamSpec

import re
import secrets

TOKEN_SEPARATOR = '@'
TOKEN_RE = re.compile(r'^[0-9a-f]{8}$')
_HAS_LETTER = re.compile(r'[a-df]')
JOINT_STATES_FRAME = 'driveline'


def new_run_token() -> str:
    """A fresh random run token: 8 lowercase hex characters (``secrets``) with at least one
    of a-d or f, so that ``--ros-args -p run_token:=<token>`` never reads it as a number
    (``75555527`` would be an INTEGER parameter, ``12345e67`` a DOUBLE: measured, the node
    then exits 2). That leaves 16**8 - 11**8 = 4.08e9 tokens: two runs draw the same one
    with probability 2.5e-10 per pair."""
    while True:
        token = secrets.token_hex(4)
        if _HAS_LETTER.search(token):
            return token


def check_run_token(token: str) -> str:
    """``token`` if it is '' or 8 lowercase hex characters, else ValueError (one line)."""
    if token and not TOKEN_RE.match(token):
        raise ValueError(f'must be empty or 8 lowercase hex characters (e.g. 3fa94c07), got {token!r}')
    return token


def tag_frame(frame: str, token: str) -> str:
    """``frame@token``; ``frame`` unchanged when ``token`` is empty."""
    return f'{frame}{TOKEN_SEPARATOR}{token}' if token else frame


def frame_token(frame_id: str) -> str | None:
    """The run token of a frame_id (text after the last ``@``), None if it has no ``@``."""
    frame, sep, token = frame_id.rpartition(TOKEN_SEPARATOR)
    return token if sep else None


def frame_token_bytes(frame_id: bytes) -> bytes | None:
    """:func:`frame_token` on the UTF-8 bytes of a frame_id (raw CDR path)."""
    frame, sep, token = frame_id.rpartition(b'@')
    return token if sep else None


def is_foreign(frame_id: str, token: str) -> bool:
    """True when ``frame_id`` carries a run token other than ``token`` (never when ``token``
    is empty: an untagged node accepts everything; untagged frame_ids are not foreign)."""
    if not token:
        return False
    other = frame_token(frame_id)
    return other is not None and other != token


def cdr_frame_id(data: bytes | memoryview) -> bytes | None:
    """``header.frame_id`` (bytes, without the NUL) of a little-endian CDR message that starts
    with a std_msgs/Header (JointState, WrenchStamped, DiagnosticArray, ...); None when the
    data is not little-endian CDR or too short.

    Layout: 4-byte encapsulation header, stamp (int32 sec, uint32 nanosec), then the string
    as uint32 length (incl. NUL) at payload offset 8 (byte 12) and its bytes from byte 16.
    """
    if len(data) < 16 or data[1] != 1:
        return None
    n = int.from_bytes(bytes(data[12:16]), 'little')
    if n < 1 or 16 + n > len(data):
        return None
    return bytes(data[16:16 + n - 1])


def cdr_is_foreign(data: bytes | memoryview, token: str) -> bool:
    """:func:`is_foreign` for a serialised Header-first message (raw subscriptions)."""
    if not token:
        return False
    frame = cdr_frame_id(data)
    if frame is None:
        return False
    other = frame_token_bytes(frame)
    return other is not None and other != token.encode()


def run_token_param() -> ParamSpec:
    """The ``run_token`` node parameter (coupling, engine, load and monitor nodes)."""
    from cvj_ros.nodes.parameters import ParamSpec
    return ParamSpec('run_token', '', 'run identity set by cvj-sim run (8 hex characters): '
                     'published in header.frame_id as <frame>@<token>; messages with another '
                     'token are ignored; empty = tag nothing, accept all (docs/ros.md "Run identity")')


def validated_run_token(params: dict[str, Any]) -> str:
    """The ``run_token`` parameter value, checked (ParameterError naming it otherwise)."""
    from cvj_ros.nodes.parameters import ParameterError
    try:
        return check_run_token(params['run_token'])
    except ValueError as exc:
        raise ParameterError('run_token', str(exc)) from None
