"""Stamps (integer ns of simulated time) and /diagnostics message helpers.

Moved out of nodes/common.py (issue 10 layout split); common.py re-exports these names.
"""

import math
from collections.abc import Mapping, Sequence
from typing import Any

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
