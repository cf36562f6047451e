"""Write an offline trace (``cvj-sim simulate --bag``) as a rosbag2 bag that ``cvj-sim
analyze`` and ``plot`` read like a run's bag.

Topics (docs/contracts.md): ``/driveline/joint_states`` (one JointState per sample: names,
position rad, velocity rad/s, effort N m), ``/engine/wrench`` and ``/load/wrench``
(torque.z, N m) and ``/driveline/scene`` (the scene, seed, fidelity report and
``mode: offline`` as YAML, like the coupling node's message). Stamps and record times are
the simulated time. No ROS needed (rosbags serialises the messages). Values are written as
float64, so analyze reads back exactly the trace's numbers.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros import bag as bagmod

ENGINE_WRENCH = '/engine/wrench'
LOAD_WRENCH = '/load/wrench'


def write_trace_bag(trace: Any, path: str | Path, *, scene_yaml: str, storage: str = 'mcap',
                    overwrite: bool = False) -> dict[str, int]:
    """Write ``trace`` (:class:`cvj_ros.physics.simulate.Trace`) to the bag ``path``;
    returns the message count per topic.

    Raises:
        BagError: the bag exists (without ``overwrite``) or the storage failed.
    """
    ts = bagmod.typestore()
    T = ts.types
    Time, Header = T['builtin_interfaces/msg/Time'], T['std_msgs/msg/Header']
    JointState, String = T['sensor_msgs/msg/JointState'], T['std_msgs/msg/String']
    Vector3, Wrench, WrenchStamped = (T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Wrench'],
                                      T['geometry_msgs/msg/WrenchStamped'])
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    names = list(trace.names)
    with bagmod.BagWriter(path, storage=storage, overwrite=overwrite) as writer:
        for topic in (bagmod.SCENE_TOPIC, bagmod.JOINT_STATES_TOPIC, ENGINE_WRENCH, LOAD_WRENCH):
            writer.add_topic(topic)
        t0_ns = int(round(float(trace.t[0]) * 1e9)) if len(trace.t) else 0
        writer.write(bagmod.SCENE_TOPIC, t0_ns,
                     ts.serialize_cdr(String(data=scene_yaml), 'std_msgs/msg/String'))
        for k, t in enumerate(np.asarray(trace.t, dtype=float)):
            ns = int(round(t * 1e9))
            hdr = Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id='')
            js = JointState(header=hdr, name=names,
                            position=np.ascontiguousarray(trace.position[k], dtype=np.float64),
                            velocity=np.ascontiguousarray(trace.velocity[k], dtype=np.float64),
                            effort=np.ascontiguousarray(trace.effort[k], dtype=np.float64))
            writer.write(bagmod.JOINT_STATES_TOPIC, ns, ts.serialize_cdr(js, 'sensor_msgs/msg/JointState'))
            for topic, series in ((ENGINE_WRENCH, trace.engine_torque), (LOAD_WRENCH, trace.load_torque)):
                msg = WrenchStamped(header=hdr, wrench=Wrench(
                    force=zero, torque=Vector3(x=0.0, y=0.0, z=float(series[k]))))
                writer.write(topic, ns, ts.serialize_cdr(msg, 'geometry_msgs/msg/WrenchStamped'))
        return dict(writer.counts)


def scene_message(scene: Any, fidelity: dict[str, Any], *, solver: dict[str, Any],
                  duration: float, sample_dt: float, names: list[str]) -> str:
    """The ``/driveline/scene`` YAML of an offline run (keys as the coupling node's)."""
    import yaml
    return yaml.safe_dump({'scene': scene.to_dict(), 'seed': scene.seed, 'fidelity': fidelity,
                           'mode': 'offline', 'coupling_scheme': 'monolithic',
                           'exchange_step': sample_dt, 'duration': duration,
                           'solver': {k: solver.get(k) for k in ('method', 'rtol', 'atol', 'backend')},
                           'shaft_names': list(names)}, sort_keys=False)
