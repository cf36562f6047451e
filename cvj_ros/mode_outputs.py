"""Bag and figure of an offline run of a scene with clutch, gearbox, brake or commands
(``cvj-sim simulate SCENE --bag/--plots``; docs/clutch_gearbox.md).

The bag has a ROS run's topics for such a scene: ``/driveline/scene`` (the scene as YAML,
``mode: offline``), ``/driveline/joint_states`` per sample (every shaft's
position, velocity and effort: the unwrapped angle, the speed and the shaft torque entering
the shaft, as the coupling node's joint states of the same scene), ``/engine/wrench`` per
sample (``torque.z`` the engine torque on the crank, stamped as the joint state it
answers; both only when the run sampled them, ``joint_samples``, else speeds only), the
commands as driver_node plays them at the scene's exchange step (``/engine/throttle``,
``/driveline/clutch``, ``/driveline/gear``, ``/driveline/brake``: a channel's sample when
its value changes) and
``/diagnostics``: one status ``cvj-sim simulate: mode event`` per located event (element,
before, after, cause, count) and the final modes in the loop status's keys
(``clutch_state.*``, ``gear.*``, ``brake_state.*``, ``mode_events``, ``stall``) with the
largest |energy residual| of the samples (``energy_residual_max_abs``). Stamps are
the simulated time in integer ns. The figure: the shaft speeds over time, the gear, and a
dotted line at every event.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cvj_ros import bag as bagmod

__all__ = ['DIAGNOSTICS_TOPIC', 'MODE_STATUS', 'EVENT_STATUS', 'mode_speeds_figure',
           'write_mode_bag', 'write_mode_plots']

DIAGNOSTICS_TOPIC = '/diagnostics'
ENGINE_WRENCH_TOPIC = '/engine/wrench'
ENGINE_FRAME = 'engine_crank'
EVENT_STATUS = 'cvj-sim simulate: mode event'
MODE_STATUS = 'cvj-sim simulate: modes'
NS_PER_S = 1_000_000_000


def _ns(t: float) -> int:
    return int(round(float(t) * NS_PER_S))


def final_mode_values(summary: dict[str, Any], result: Any) -> dict[str, str]:
    """The final modes in the coupling node's loop-status keys (report.py reads them)."""
    mode = result.final_mode
    out: dict[str, str] = {}
    for name, text in summary['final_modes'].items():
        if name in mode.gear:
            out[f'gear.{name}'] = str(mode.gear[name])
        elif name in mode.clutch or name in mode.packs:
            out[f'clutch_state.{name}'] = text
        else:
            out[f'brake_state.{name}'] = text
    out['mode_events'] = str(len(result.events))
    resid = np.asarray(result.energy_residual, dtype=float)
    resid = resid[np.isfinite(resid)]
    if resid.size:
        out['energy_residual_max_abs'] = repr(float(np.max(np.abs(resid))))
    out['stall'] = result.stall or ''
    return out


def write_mode_bag(scene: Any, result: Any, summary: dict[str, Any], path: str | Path, *,
                   scene_yaml: str, exchange_step: float | None = None,
                   storage: str = 'mcap', overwrite: bool = False) -> dict[str, int]:
    """Write the run ``result`` (:class:`cvj_ros.physics.hybrid.simulate.HybridResult`) of
    ``scene`` to the bag ``path`` (module docstring); returns the message count per topic.

    Raises:
        BagError: the bag exists (without ``overwrite``) or the storage failed.
    """
    from cvj_ros.nodes.command_plan import CHANNEL_TOPICS, CommandPlan
    ts = bagmod.typestore()
    T = ts.types
    Time, Header = T['builtin_interfaces/msg/Time'], T['std_msgs/msg/Header']
    JointState, String = T['sensor_msgs/msg/JointState'], T['std_msgs/msg/String']
    Float64, Int8 = T['std_msgs/msg/Float64'], T['std_msgs/msg/Int8']
    Wrench, WrenchStamped, Vector3 = (T['geometry_msgs/msg/Wrench'],
                                      T['geometry_msgs/msg/WrenchStamped'],
                                      T['geometry_msgs/msg/Vector3'])
    Array, Status, KeyValue = (T['diagnostic_msgs/msg/DiagnosticArray'],
                               T['diagnostic_msgs/msg/DiagnosticStatus'],
                               T['diagnostic_msgs/msg/KeyValue'])

    def header(ns: int, frame_id: str = '') -> Any:
        return Header(stamp=Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S), frame_id=frame_id)

    def status(ns: int, name: str, message: str, values: dict[str, str], level: int = 0) -> bytes:
        st = Status(level=level, name=name, message=message,
                    hardware_id='cvj-sim', values=[KeyValue(key=k, value=v) for k, v in values.items()])
        return ts.serialize_cdr(Array(header=header(ns), status=[st]),
                                'diagnostic_msgs/msg/DiagnosticArray')

    h = float(exchange_step or scene.exchange_step)
    h_ns = max(1, _ns(h))
    n_steps = int(result.t_end * NS_PER_S // h_ns)
    plan = CommandPlan.from_scene(scene, h_ns, n_steps) if scene.commands else None
    empty = np.zeros(0, dtype=np.float64)
    position, effort, engine = (getattr(result, k, None) for k in ('position', 'effort', 'engine_torque'))
    zero = Vector3(x=0.0, y=0.0, z=0.0)
    with bagmod.BagWriter(path, storage=storage, overwrite=overwrite) as writer:
        for topic in (bagmod.SCENE_TOPIC, bagmod.JOINT_STATES_TOPIC, DIAGNOSTICS_TOPIC):
            writer.add_topic(topic)
        if engine is not None:
            writer.add_topic(ENGINE_WRENCH_TOPIC)
        for c in plan.channels if plan else ():
            writer.add_topic(CHANNEL_TOPICS[c])
        writer.write(bagmod.SCENE_TOPIC, 0, ts.serialize_cdr(String(data=scene_yaml), 'std_msgs/msg/String'))
        # every message in time order; at equal stamps commands before the state they act on
        msgs: list[tuple[int, int, str, bytes]] = []
        for k, step in (plan or ()):
            for channel, value in step:
                data = (ts.serialize_cdr(Int8(data=int(value)), 'std_msgs/msg/Int8') if channel == 'gear'
                        else ts.serialize_cdr(Float64(data=float(value)), 'std_msgs/msg/Float64'))
                msgs.append((k * h_ns, 0, CHANNEL_TOPICS[channel], data))
        for k, t in enumerate(np.asarray(result.t, dtype=float)):
            ns = _ns(t)
            js = JointState(header=header(ns), name=list(result.shafts),
                            position=(empty if position is None
                                      else np.ascontiguousarray(position[k], dtype=np.float64)),
                            velocity=np.ascontiguousarray(result.speed[k], dtype=np.float64),
                            effort=(empty if effort is None
                                    else np.ascontiguousarray(effort[k], dtype=np.float64)))
            msgs.append((ns, 1, bagmod.JOINT_STATES_TOPIC, ts.serialize_cdr(js, 'sensor_msgs/msg/JointState')))
            if engine is not None:
                w = WrenchStamped(header=header(ns, ENGINE_FRAME),
                                  wrench=Wrench(force=zero, torque=Vector3(x=0.0, y=0.0, z=float(engine[k]))))
                msgs.append((ns, 1, ENGINE_WRENCH_TOPIC,
                             ts.serialize_cdr(w, 'geometry_msgs/msg/WrenchStamped')))
        for i, e in enumerate(result.events):
            ns = _ns(e.t)
            msgs.append((ns, 2, DIAGNOSTICS_TOPIC, status(
                ns, EVENT_STATUS, f'{e.element}: {e.before} -> {e.after} ({e.cause})',
                {'t_s': repr(float(e.t)), 'element': e.element, 'before': e.before,
                 'after': e.after, 'cause': e.cause, 'mode_events': str(i + 1)})))
        end = _ns(result.t_end)
        msgs.append((end, 3, DIAGNOSTICS_TOPIC, status(
            end, MODE_STATUS, result.stall or 'end of run', final_mode_values(summary, result),
            level=1 if result.stall else 0)))
        for ns, _order, topic, data in sorted(msgs, key=lambda m: (m[0], m[1])):
            writer.write(topic, ns, data)
        return dict(writer.counts)


def mode_speeds_figure(result: Any, title: str) -> Any:
    """Shaft speeds (rad/s) over time above the engaged gear, a dotted line at every event
    (colour per element); matplotlib Figure (caller saves and closes)."""
    from cvj_ros.plots import plt, series_style, shaft_labels
    labels = shaft_labels(result.shafts)
    n_entries = len(labels) + len(set(e.element for e in result.events))
    ncol = 1 if n_entries <= 16 else 2        # a vehicle's ~30 entries: two columns
    fig, (ax, axg) = plt.subplots(2, 1, sharex=True, figsize=(10 + 2.5 * (ncol - 1), 6.5),
                                  gridspec_kw={'height_ratios': [3, 1]})
    for i, name in enumerate(labels):
        ax.plot(result.t, result.speed[:, i], label=name, **series_style(i))
    elements = list(dict.fromkeys(e.element for e in result.events))
    colours = plt.get_cmap('tab10')
    for e in result.events:
        c = colours(elements.index(e.element) % 10)
        for a in (ax, axg):
            a.axvline(e.t, color=c, linestyle=':', linewidth=0.9)
    from matplotlib.lines import Line2D
    handles, names = ax.get_legend_handles_labels()
    handles += [Line2D([], [], color=colours(i % 10), linestyle=':') for i in range(len(elements))]
    names += [f'event: {el}' for el in elements]
    right = 0.80 if ncol == 1 else 0.68      # the legend beside both panels, not stretching them
    fig.legend(handles, names, loc='upper left', bbox_to_anchor=(right, 0.98), fontsize='small',
               ncol=ncol)
    ax.set_ylabel('shaft speed (rad/s)')
    ax.set_title(f'{title}: {len(result.events)} mode events')
    ax.grid(alpha=0.3)
    axg.step(result.t, result.gear, where='post', color='k')
    axg.set_ylabel('gear')
    axg.set_xlabel('t (s)')
    axg.grid(alpha=0.3)
    fig.tight_layout(rect=(0.0, 0.0, right, 1.0))
    return fig


def write_mode_plots(scene: Any, result: Any, out_dir: str | Path) -> list[Path]:
    """``mode_speeds.png`` (:func:`mode_speeds_figure`) in ``out_dir`` (created)."""
    from cvj_ros.plots import plt
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig = mode_speeds_figure(result, scene.name)
    path = out / 'mode_speeds.png'
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
