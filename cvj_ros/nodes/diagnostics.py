"""Stamps (integer ns of simulated time) and /diagnostics message helpers.

Moved out of nodes/common.py (layout split); common.py re-exports these names.
"""

import functools
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue


from cvj_ros.nodes.parameters import NS_PER_S

# DiagnosticStatus levels (bytes in rclpy).
OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE

def ns_to_stamp(ns: int) -> Time:
    """builtin_interfaces/Time from integer nanoseconds (simulated time)."""
    return Time(sec=int(ns // NS_PER_S), nanosec=int(ns % NS_PER_S))


def stamp_to_ns(stamp: Time) -> int:
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def diag_status(name: str, level: bytes, message: str, values: Mapping[str, Any] | None = None,
                *, hardware_id: str = 'cvj_ros') -> DiagnosticStatus:
    """A DiagnosticStatus with key/values (floats formatted with 6 significant digits)."""
    kv = []
    for k, v in (values or {}).items():
        kv.append(KeyValue(key=str(k), value=f'{v:.6g}' if isinstance(v, float) else str(v)))
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=kv)


class Status(NamedTuple):
    """One diagnostic status as plain values (what :func:`publish_statuses` encodes
    without building rclpy messages): level (DiagnosticStatus level, bytes of 1), name,
    message, hardware_id, values ((key, value) str pairs)."""
    level: bytes
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def plain_status(name: str, level: bytes, message: str, values: Mapping[str, Any] | None = None,
                 *, hardware_id: str = 'cvj_ros') -> Status:
    """:func:`diag_status` as a :class:`Status` (the same value formatting)."""
    return Status(level, name, message, hardware_id,
                  tuple((str(k), f'{v:.6g}' if isinstance(v, float) else str(v))
                        for k, v in (values or {}).items()))


def status_message(status: Status) -> DiagnosticStatus:
    """The rclpy DiagnosticStatus of a :class:`Status`."""
    return DiagnosticStatus(level=status.level, name=status.name, message=status.message,
                            hardware_id=status.hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in status.values])


@functools.lru_cache(maxsize=1)
def diagnostic_array_encoder() -> Any:
    """The process's DiagnosticArrayEncoder (built and self-checked once, ~1-5 ms: every
    node builds it when created, not at its first publication inside a loop)."""
    from cvj_ros.nodes.cdr import DiagnosticArrayEncoder
    return DiagnosticArrayEncoder()


def publish_statuses(publisher: Any, stamp_ns: int, frame_id: str, statuses: Sequence[Status]) -> None:
    """Publish one DiagnosticArray of ``statuses`` at ``stamp_ns`` (integer ns) as CDR
    bytes (cvj_ros.nodes.cdr.DiagnosticArrayEncoder; rclpy messages if its self-check failed)."""
    encoder = diagnostic_array_encoder()
    if encoder.ok:
        publisher.publish(encoder.encode(stamp_ns, frame_id, statuses))
        return
    msg = diag_array(stamp_ns, [status_message(st) for st in statuses])
    msg.header.frame_id = frame_id
    publisher.publish(msg)


def diag_array(stamp_ns: int, statuses: Sequence[DiagnosticStatus]) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.status = list(statuses)
    return msg


def level_for(value: float, warn: float, error: float) -> bytes:
    """OK below ``warn``, WARN below ``error``, ERROR at or above (NaN -> ERROR)."""
    if not math.isfinite(value) or value >= error:
        return ERROR
    return WARN if value >= warn else OK


# --- pre-serialised messages (CDR) ----------------------------------------------------------
#
# rclpy publish() of a message object converts it field by field from Python to C (JointState
# with 13 names: about 15 us, WrenchStamped 13 us, Clock 3.5 us here); publish() of ``bytes``
# hands the serialised sample to the middleware as is (3.5 us). The encoders below write the
# CDR of the loop's messages directly: ROS 2 serialisation = OMG XCDR1 little endian
# (encapsulation header 00 01 00 00, primitives aligned to their size relative to the
# payload start, strings as uint32 length incl. NUL + bytes + NUL). Each encoder checks itself
# once against rclpy.serialization (same length, decodes to the same message); ``ok`` is
# False otherwise (then the caller publishes message objects).
