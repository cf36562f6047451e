"""QoS profiles shared by every cvj_ros node, the recorder and replay.

* :data:`DATA_QOS` - data topics (/clock, /driveline/joint_states, /engine/wrench,
  /load/wrench, /coupling/<joint>/wrench, /diagnostics, /engine/throttle):
  reliable, volatile, keep_last depth 10000 (10 s of a 1 ms loop), so a lockstep run loses
  no sample even when a subscriber lags by many exchange steps. The writer's depth is the
  bound that matters for the recorder: a sample that a starved reader has not acknowledged
  is resent from the writer's history, and a keep_last writer drops the oldest once it holds
  ``depth``. At depth 1000 the first run's bag in
  ``test_second_run_on_the_same_domain_is_refused_and_mixes_nothing`` lost thousands of its
  joint states after the second run started (4402 of 13190 in one try), with two CPU
  burners (8 of about 20 tries, code of stops 22 and 23 alike); at 10000, 6 of 6 complete. Peak RSS of every node process of a
  kavz685_lever run unchanged (the history is allocated as it fills; acknowledged samples
  leave it).
* :data:`RECORDER_QOS` - the recorder's subscriptions to data topics: as DATA_QOS with
  depth 10000 (10 s of a 1 ms loop). The loop does not wait for the recorder: a reader
  that does not take its samples keeps only the newest ``depth`` of them. With the compiled
  loop at ~1 ms per exchange, a recorder thread starved for ~1.1 s (2 CPU burners, GIL
  shared with the test's threads) lost the first 100 of 1108 joint states at depth 1000;
  10000 costs ~2.4 MiB more RSS for 6 topics with 3000 queued 13-shaft states each
  (measured 66.5 vs 68.9 MiB).
* :data:`LATCHED_QOS` - /driveline/scene: reliable, transient_local, depth 1, so a
  late subscriber (recorder, monitor) still receives the one scene message.
"""
from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

DATA_DEPTH = 10000

DATA_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=DATA_DEPTH,
)

RECORDER_DEPTH = 10000

RECORDER_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
    history=HistoryPolicy.KEEP_LAST,
    depth=RECORDER_DEPTH,
)

LATCHED_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
)

# Topic names.
CLOCK_TOPIC = '/clock'
JOINT_STATES_TOPIC = '/driveline/joint_states'
ENGINE_WRENCH_TOPIC = '/engine/wrench'
ENGINE_THROTTLE_TOPIC = '/engine/throttle'
# the shift schedule's torque intervention: factor on the pedal for step k (coupling node)
ENGINE_THROTTLE_SCALE_TOPIC = '/engine/throttle_scale'
CLUTCH_TOPIC = '/driveline/clutch'
GEAR_TOPIC = '/driveline/gear'
BRAKE_TOPIC = '/driveline/brake'
LOAD_WRENCH_TOPIC = '/load/wrench'
SCENE_TOPIC = '/driveline/scene'
DIAGNOSTICS_TOPIC = '/diagnostics'
# the run's recorder: record time (rosgraph_msgs/Clock) of what its bag holds on disk
RECORDED_TOPIC = '/driveline/recorded'
#: a hand-started recorder (`cvj-sim record`) reports here (std_msgs/String, latched, JSON)
#: how many publishers each of its readers has matched, whenever that changes
RECORDER_READY_TOPIC = '/driveline/recorder_ready'


def qos_match(pub: Any, sub: Any) -> bool:
    """The request/offer rules of reliability and durability between a publisher's and a
    subscription's QoS (the policies these topics set; rclpy's qos_check_compatible also
    compares deadline and liveliness, which the ROS graph reports in another form and calls
    incompatible)."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
    if pub.reliability == ReliabilityPolicy.BEST_EFFORT and sub.reliability == ReliabilityPolicy.RELIABLE:
        return False
    return not (pub.durability == DurabilityPolicy.VOLATILE
                and sub.durability == DurabilityPolicy.TRANSIENT_LOCAL)


def type_name(cls: Any) -> str:
    """``pkg/msg/Name`` of a message class, as the ROS graph names topic types."""
    return f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}'


def coupling_wrench_topic(joint: str) -> str:
    """Topic of the reaction wrench of scene joint ``joint``: ``/coupling/<joint>/wrench``."""
    return f'/coupling/{joint}/wrench'


# --- DDS settings of the node processes ---------------------------------------------------

# Fast DDS default profiles of a run's processes (unless the user gives a file):
# * writers: heartbeats every 20 ms instead of Fast DDS's 3 s, so a sample dropped on the way
#   to a busy subscriber (shared-memory port full on a loaded 2-core machine) is repaired
#   within milliseconds, and a writer's wait for acknowledgements at exit ends as soon as
#   all arrived;
# * writers: NACK suppression 20 ms instead of Fast DDS's 0. Fast DDS (re)starts a reader
#   proxy's nack-suppression timer for every sample sent to a reader in another process; at 0
#   the timer was idle again before the next sample, so every sample woke the participant's
#   event thread (and its writer-mutex hand-offs): measured with `perf` sched_wakeup stacks in
#   a separate-process kavz685_lever run, ~3 event-thread wakes per exchange in the coupling
#   process (ReaderProxy::from_unsent_to_status -> ResourceEvent::notify), 2-3 in engine and
#   load; context switches of all processes 36-37 -> 17-18 per exchange with 20 ms (the
#   event threads drop out). A timer still armed is not restarted, so it fires once per
#   20 ms. The cost: a sample lost on the way (shared-memory port full) is NACKed within the
#   suppression window in vain, so its repair can take one heartbeat longer (<= ~45 ms);
#   reliability is unchanged (docs/nodes.md, "Separate processes: the DDS event thread");
# * participants: a discovery announcement every 0.25 s instead of 3 s. A participant that
#   starts after another learns of it only from the other's next periodic announcement:
#   the recorder's participant exists before the node processes start, so `cvj-sim run`
#   waited ~2.5 s for its peers to be discovered (measured, kavz685_lever 0.5 s: peers
#   connected at 4.0 s, whole command 6.1-6.7 s; with this profile in the recorder's
#   process 1.6-1.8 s and 4.0-4.3 s). Four small messages a second per participant.
FASTDDS_PROFILE = '''<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="cvj_ros_participant" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          <leaseAnnouncement><sec>0</sec><nanosec>250000000</nanosec></leaseAnnouncement>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
  <publisher profile_name="cvj_ros_writer" is_default_profile="true">
    <times>
      <heartbeatPeriod><sec>0</sec><nanosec>20000000</nanosec></heartbeatPeriod>
      <nackSupressionDuration><sec>0</sec><nanosec>20000000</nanosec></nackSupressionDuration>
    </times>
  </publisher>
</profiles>
'''
FASTDDS_PROFILE_NAME = 'fastdds_profile.xml'


@contextlib.contextmanager
def process_dds_profile(env: dict[str, str]) -> Iterator[None]:
    """While the block runs, this process's ``FASTRTPS_DEFAULT_PROFILES_FILE`` is ``env``'s
    (from :func:`dds_environment`; a value the user set wins). Fast DDS reads the file when
    the process creates its first participant and keeps it, so a participant created in the
    block (`cvj-sim run`'s recorder) gets :data:`FASTDDS_PROFILE` when it is the process's
    first; later ones in a long-lived process (tests) keep what the first one loaded."""
    import os
    key = 'FASTRTPS_DEFAULT_PROFILES_FILE'
    if os.environ.get(key) or not env.get(key):
        yield
        return
    os.environ[key] = env[key]
    try:
        yield
    finally:
        os.environ.pop(key, None)


def dds_environment(env: dict[str, str], *, profile_dir: str | None = None) -> dict[str, str]:
    """``env`` with the DDS settings of the cvj_ros node processes (values already set win).

    * ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, ``RMW_IMPLEMENTATION=rmw_fastrtps_cpp``;
    * ``RMW_FASTRTPS_PUBLICATION_MODE=SYNCHRONOUS``: publish() puts the sample on the
      transport before returning, so the samples a node publishes just before it exits
      (the coupling node's final state) reach the recorder (measured: in asynchronous mode
      up to 5 final joint states of 201 were lost);
    * with Fast DDS and ``profile_dir`` given and no ``FASTRTPS_DEFAULT_PROFILES_FILE`` set:
      :data:`FASTDDS_PROFILE` written to ``<profile_dir>/fastdds_profile.xml`` and used.
    """
    import os
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    env.setdefault('RMW_FASTRTPS_PUBLICATION_MODE', 'SYNCHRONOUS')
    if (profile_dir is not None and env.get('RMW_IMPLEMENTATION') == 'rmw_fastrtps_cpp'
            and not env.get('FASTRTPS_DEFAULT_PROFILES_FILE')):
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = write_profile(profile_dir)
    return env


def write_profile(profile_dir: str) -> str:
    """:data:`FASTDDS_PROFILE` as ``<profile_dir>/fastdds_profile.xml`` (written to a
    temporary name and renamed, so a process reading it never sees half a file); its path."""
    import os
    import tempfile
    os.makedirs(profile_dir, exist_ok=True)
    path = os.path.join(profile_dir, FASTDDS_PROFILE_NAME)
    fd, tmp = tempfile.mkstemp(dir=profile_dir, prefix='.fastdds_profile.')
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as fh:
            fh.write(FASTDDS_PROFILE)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


#: the largest ROS_DOMAIN_ID whose DDS ports fit: Fast DDS's ports are 7400 + 250 x domain +
#: offsets (up to 11), at most 65535 (ROS 2 documentation, "The ROS_DOMAIN_ID")
MAX_DOMAIN_ID = 232


def domain_id(env: dict[str, str] | None = None, default: int = 0) -> int:
    """The ROS_DOMAIN_ID of ``env`` (default: this process's environment) as an integer,
    ``default`` when unset or empty; a :class:`~cvj_ros.errors.CvjError` naming the variable
    when it is not an integer from 0 to :data:`MAX_DOMAIN_ID` (where the DDS layer would
    otherwise fail with its own log lines and no message of ours)."""
    import os

    from cvj_ros.errors import CvjError
    raw = (os.environ if env is None else env).get('ROS_DOMAIN_ID', '')
    if not raw.strip():
        return default
    try:
        domain = int(raw)
    except ValueError:
        raise CvjError(f'ROS_DOMAIN_ID: must be an integer, got {raw!r}') from None
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise CvjError(f'ROS_DOMAIN_ID: must be from 0 to {MAX_DOMAIN_ID} (DDS ports '
                       f'7400 + 250 x domain must stay under 65536), got {domain}')
    return domain


def node_dds_defaults() -> None:
    """In a node process started by hand (console script, ``ros2 run``, the launch file) or
    in ``cvj-sim record``: the two DDS settings of `cvj-sim run`'s processes that make
    delivery complete - synchronous publication and :data:`FASTDDS_PROFILE` (20 ms
    heartbeats) - set in this process's environment where the user set none, before its
    first participant. The RMW and the discovery range stay the user's; another RMW than
    Fast DDS gets nothing."""
    import os
    import tempfile
    if os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') not in ('', 'rmw_fastrtps_cpp'):
        return
    os.environ.setdefault('RMW_FASTRTPS_PUBLICATION_MODE', 'SYNCHRONOUS')
    if os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE') or os.environ.get('FASTDDS_DEFAULT_PROFILES_FILE'):
        return
    try:
        path = write_profile(os.path.join(tempfile.gettempdir(), f'cvj_ros_dds_{os.getuid()}'))
    except OSError:
        return      # no writable temp dir: Fast DDS's defaults
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = path
