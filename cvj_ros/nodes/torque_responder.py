"""TorqueResponder: the node that answers each joint state with a stamped torque (engine, load).

Moved out of nodes/common.py (layout split); common.py re-exports these names.
"""

import math
from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray


from cvj_ros.nodes.executor import CvjNode
from cvj_ros.nodes.diagnostics import ERROR, WARN, plain_status, publish_statuses
from cvj_ros.nodes.parameters import NS_PER_S, ParameterError
from cvj_ros.nodes.cdr import CdrError, WrenchStampedEncoder
from cvj_ros.nodes.malformed import MALFORMED_KEY, MalformedInputs
from cvj_ros.nodes.qos import JOINT_STATES_TOPIC

class TorqueResponder(CvjNode):
    """Answers every /driveline/joint_states sample with a WrenchStamped from a torque source.

    ``torque.z`` = ``source.torque(t, omega, phi)`` (N m) at the speed omega (rad/s) and
    unwrapped angle phi (rad) of shaft ``shaft`` in the joint-state message, t (s) = its
    stamp; the answer's stamp echoes the joint-state stamp exactly and its frame_id is the
    shaft name. Joint states that arrive while /driveline/joint_states has more than one
    publisher are not answered (counted in ``foreign_states``; cvj_ros.nodes.peers).
    A non-finite input or torque is never published: an ERROR diagnostic names it (the
    coupling node then times out with a clear error). A joint state that does not decode
    (:class:`~cvj_ros.nodes.cdr.CdrError`) or lacks the shaft is not answered: counted in
    ``malformed_messages``, the first one named in one WARN line.
    """

    def start_answering(self, *, source: Any, shaft: str, wrench_topic: str) -> None:
        """Create the publishers and the joint-state subscription (call once, after validation)."""
        from geometry_msgs.msg import WrenchStamped
        from sensor_msgs.msg import JointState

        from cvj_ros.nodes.qos import DATA_QOS, DIAGNOSTICS_TOPIC
        self._wrench_cls = WrenchStamped
        self.source = source
        self.shaft = shaft
        self.answered = 0
        self.foreign_states = 0          # joint states while the topic had two publishers
        self.malformed = MalformedInputs(self.get_logger())   # joint states not answerable
        self._diag_frame = self.get_name()
        self._names: list[str] | None = None
        self._index = -1
        self.last_stamp_ns = 0
        self._wrench_topic = wrench_topic
        from cvj_ros.nodes.intra import loop_publisher, loop_subscription
        self.wrench_pub = loop_publisher(self, WrenchStamped, wrench_topic, DATA_QOS)
        self.diag_pub = loop_publisher(self, DiagnosticArray, DIAGNOSTICS_TOPIC, DATA_QOS)
        # one answer message, reused (publish() serialises it before returning)
        self._answer = WrenchStamped()
        self._answer.header.frame_id = shaft
        self._answer_torque = self._answer.wrench.torque
        self._answer_cdr = WrenchStampedEncoder(shaft)
        # raw CDR read by JointStateDecoder: rclpy's Python JointState per sample cost ~4x more
        # (docs/nodes.md, composed mode); _on_joint_states takes either form
        from cvj_ros.nodes.cdr import JointStateDecoder, ShaftReader
        self._decode = JointStateDecoder().decode
        self._read_shaft = ShaftReader(shaft).read
        self.js_sub = loop_subscription(self, JointState, JOINT_STATES_TOPIC,
                                        self._on_joint_states_raw, DATA_QOS)
        # run identity by publisher (cvj_ros.nodes.peers): through DDS, joint states are
        # answered only while the topic has one publisher (in composed mode the in-process
        # bus brings only the hosted coupling node's)
        self._js_dds = not hasattr(self.js_sub, 'bus')

    def _shaft_index(self, names: Sequence[str]) -> int:
        if self._names is None or list(names) != self._names:
            self._names = list(names)
            self._index = self._names.index(self.shaft) if self.shaft in self._names else -1
        return self._index

    def report(self, level: bytes, message: str, values: Mapping[str, Any] | None = None) -> None:
        """Publish one diagnostic status named after this node (and log it when not OK)."""
        if level == ERROR:
            self.get_logger().error(message)
        elif level == WARN:
            self.get_logger().warning(message)
        publish_statuses(self.diag_pub, self.last_stamp_ns, self._diag_frame,
                         [plain_status(self.get_name(), level, message, values)])

    def _on_joint_states_raw(self, data: bytes) -> None:
        """A serialised joint state: the shaft's angle and speed read in place
        (:class:`~cvj_ros.nodes.cdr.ShaftReader`: the loop's samples keep one layout), else
        decoded whole (:meth:`_on_joint_states` names what is missing)."""
        if self._js_dds and self.js_sub.get_publisher_count() > 1:
            self._stranger_state()
            return
        got = self._read_shaft(data)
        if got is None:
            try:
                msg = self._decode(data)
            except CdrError as exc:
                self._drop(str(exc))
                return
            self._on_joint_states(msg)
            return
        sec, nanosec, frame, phi, omega = got
        self._answer_state(sec, nanosec, frame, phi, omega)

    def _on_joint_states(self, msg: Any) -> None:
        """Answer one joint state (a JointState or a :class:`~cvj_ros.nodes.cdr.JointStateView`)."""
        stamp = msg.header.stamp
        names = msg.name
        i = self._index if names == self._names else self._shaft_index(names)
        if i < 0 or i >= len(msg.velocity) or i >= len(msg.position):
            names = ', '.join(msg.name[:8]) + (f', ... ({len(msg.name)} names)'
                                               if len(msg.name) > 8 else '')
            self._drop(f'no shaft {self.shaft!r} with position and velocity; names: {names}')
            return
        self._answer_state(stamp.sec, stamp.nanosec, msg.header.frame_id,
                           float(msg.position[i]), float(msg.velocity[i]))

    def _stranger_state(self) -> None:
        """A joint state while /driveline/joint_states has more than one publisher: whose it
        is cannot be told, so it is not answered (``foreign_states``; the first one named in
        one WARN line). The coupling node stops its run naming the intruder."""
        self.foreign_states += 1
        if self.foreign_states == 1:
            from cvj_ros.nodes.peers import describe, publisher_endpoints
            self.get_logger().warning(
                f'{JOINT_STATES_TOPIC} has {self.js_sub.get_publisher_count()} publishers '
                f'({describe(publisher_endpoints(self, JOINT_STATES_TOPIC))}): not answering '
                f'while more than one node publishes joint states')

    def _drop(self, reason: str, topic: str = JOINT_STATES_TOPIC) -> None:
        """A message on ``topic`` this node cannot use (undecodable; a joint state without its
        shaft): dropped, counted in ``malformed_messages``, the first one per topic in one
        WARN line (log and /diagnostics); an unanswered state is then named by the coupling
        node's wait."""
        line = self.malformed.drop(topic, reason)
        if line is not None:
            publish_statuses(self.diag_pub, self.last_stamp_ns, self._diag_frame,
                             [plain_status(self.get_name(), WARN, line,
                                           {MALFORMED_KEY: self.malformed.total})])

    def _answer_state(self, sec: int, nanosec: int, frame: str, phi: float, omega: float) -> None:
        """Answer the state of the shaft at stamp (sec, nanosec): angle ``phi`` (rad), speed
        ``omega`` (rad/s), from a joint state with header.frame_id ``frame``."""
        self.last_stamp_ns = sec * NS_PER_S + nanosec
        if not (math.isfinite(omega) and math.isfinite(phi)):
            self.report(ERROR, f'/driveline/joint_states: {self.shaft} position/velocity not finite '
                               f'({phi}, {omega}); not answered')
            return
        t = self.last_stamp_ns / NS_PER_S
        torque = float(self.source.torque(t, omega, phi))
        if not math.isfinite(torque):
            self.report(ERROR, f'{self._wrench_topic}: model torque not finite ({torque}) at '
                               f't={t} s, omega={omega} rad/s; not published')
            return
        if self._answer_cdr.ok:
            self.wrench_pub.publish(self._answer_cdr.encode(sec, nanosec,
                                                            0.0, 0.0, 0.0, 0.0, 0.0, torque))
        else:
            out = self._answer
            out.header.stamp.sec, out.header.stamp.nanosec = sec, nanosec
            self._answer_torque.z = torque
            self.wrench_pub.publish(out)
        self.answered += 1


def load_torque_series_file(name: str, path: str) -> tuple[Any, Any]:
    """Read a load torque time series: ``.npz`` with arrays ``t`` (s) and ``torque`` (N m),
    or YAML/JSON with the same keys as lists. Raises ParameterError naming ``name``."""
    import numpy as np
    import yaml
    try:
        if path.endswith('.npz'):
            with np.load(path) as data:
                t, torque = np.asarray(data['t'], float), np.asarray(data['torque'], float)
        else:
            with open(path, encoding='utf-8') as fh:
                data = yaml.safe_load(fh)
            if not isinstance(data, dict):
                raise ParameterError(name, f'{path}: must be a mapping with keys t and torque')
            t = np.asarray(data['t'], float)
            torque = np.asarray(data['torque'], float)
    except OSError as exc:
        raise ParameterError(name, f'{path}: cannot read ({exc.strerror or exc})') from None
    except KeyError as exc:
        raise ParameterError(name, f'{path}: missing array {exc.args[0]!r} (need t and torque)') from None
    except (ValueError, TypeError, yaml.YAMLError) as exc:
        raise ParameterError(name, f'{path}: {str(exc).splitlines()[0]}') from None
    if t.ndim != 1 or t.shape != torque.shape or t.size < 2:
        raise ParameterError(name, f'{path}: t and torque must be 1-D arrays of equal length >= 2')
    return t, torque
