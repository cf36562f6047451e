"""Real-time factor of `cvj-sim run` composed vs separate processes, and the overhead per
exchange against the round trip of the same topology (results in docs/nodes.md).

For each scene and mode, ``--runs`` runs of ``cvj-sim run SCENE --duration D
--exchange-step H [--composed]`` (each in a fresh process, as a user starts it); from each
run's report.json and the coupling node's last loop diagnostics:

* real-time factor (simulated s / loop wall s) and wall per exchange (us);
* integration (us per exchange, the stepper's ``advance``) and the overhead per exchange =
  wall per exchange - integration: the messaging, peers' answers and recording;
* ratio = overhead / round trip of the same topology: composed <-> in-process 2-peer round
  trip (:func:`round_trip_in_process`: one pinging node and two answering nodes on one
  EventsExecutor, spun like the coupling loop), separate <-> inter-process 2-peer round trip
  (:func:`cvj_ros.nodes.roundtrip.measure_round_trip_ipc`, echoes=2).

The machine's load average is printed before and after: on a shared 2-core machine the
numbers move by 2-4x with the load of other processes; compare runs taken together.

Usage: ``python scripts/bench_composed.py [--scenes kavz685_lever fwd_halfshaft]
[--duration 5] [--exchange-step 0.001] [--runs 3] [--modes composed composed-dds separate]
[--json OUT.json]`` (``composed-dds``: composed with ``--no-intra-process``, every message
through DDS as before the in-process bus).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any


def round_trip_in_process(n: int = 2000, peers: int = 2, *, warmup: int = 100,
                          timeout: float = 60.0) -> dict[str, float]:
    """In-process round trip with ``peers`` answering nodes on one EventsExecutor (us):
    :func:`cvj_ros.nodes.roundtrip.measure_round_trip_peers` (moved there for the bench)."""
    from cvj_ros.nodes.roundtrip import measure_round_trip_peers
    return measure_round_trip_peers(n, peers, warmup=warmup, timeout=timeout)


def loop_status(bag_path: Path) -> dict[str, float]:
    """The coupling node's last 'coupling_node: loop' diagnostic values (floats)."""
    from cvj_ros import bag
    diags = bag.read_bag(bag_path, ['/diagnostics'])['/diagnostics']
    for statuses in reversed(diags.statuses):
        for st in statuses:
            if st['name'] == 'coupling_node: loop':
                return {k: float(v) for k, v in st['values'].items()}
    return {}


def _children_cpu_s() -> float:
    """User + system CPU s of every finished, waited-for descendant (cvj-sim and its nodes)."""
    import resource
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


MODE_ARGS = {'composed': ['--composed'],
             'composed-dds': ['--composed', '--no-intra-process'],   # every message through DDS
             'separate': []}


def run_once(scene: str, composed: bool | str, duration: float, h: float) -> dict[str, Any]:
    """One `cvj-sim run` in a fresh process: report figures, coupling loop statistics and
    ``cpu_s``, the CPU time of cvj-sim and all its node processes (start-up included)."""
    cvj_sim = str(Path(sys.executable).with_name('cvj-sim'))
    cpu0 = _children_cpu_s()
    with tempfile.TemporaryDirectory(prefix='cvj_bench_') as tmp:
        out = Path(tmp) / 'run'
        cmd = [cvj_sim, 'run', scene, '--out', str(out), '--duration', str(duration),
               '--exchange-step', str(h)] + (MODE_ARGS[composed] if isinstance(composed, str)
                                             else ['--composed'] if composed else [])
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        cpu_s = _children_cpu_s() - cpu0
        if r.returncode != 0:
            raise RuntimeError(f'{" ".join(cmd)}: exit {r.returncode}\n{r.stdout}{r.stderr}')
        rep = json.loads((out / 'report.json').read_text())
        st = loop_status(out / 'bag')
    wall_us = rep['wall_per_step'] * 1e6
    return {'rtf': rep['real_time_factor'], 'wall_us': wall_us,
            'integration_us': st.get('integration_us_mean', float('nan')),
            'overhead_us': wall_us - st.get('integration_us_mean', float('nan')),
            'cpu_us': st.get('process_cpu_us_mean', float('nan')), 'cpu_s': cpu_s,
            'steps': rep['counts'].get('/driveline/joint_states', 1) - 1}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--scenes', nargs='+', default=['kavz685_lever', 'fwd_halfshaft'])
    ap.add_argument('--duration', type=float, default=5.0)
    ap.add_argument('--exchange-step', type=float, default=1e-3)
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--json', type=Path, default=None)
    ap.add_argument('--modes', nargs='+', choices=sorted(MODE_ARGS), default=['composed', 'separate'],
                    help='composed (in-process bus), composed-dds (--no-intra-process), separate')
    a = ap.parse_args()
    from cvj_ros.nodes.roundtrip import measure_round_trip_ipc, run_dds_settings
    run_dds_settings()     # the node processes' DDS settings (profile too), also for the round trips
    load0 = os.getloadavg()
    print(f'load average before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f} ({os.cpu_count()} cores)')
    rt_in = round_trip_in_process(peers=2)
    rt_ipc = measure_round_trip_ipc(n=2000, echoes=2)
    print(f'round trip, 2 peers: in-process {rt_in["us_mean"]:.0f} us (p50 {rt_in["us_p50"]:.0f}), '
          f'inter-process {rt_ipc["us_mean"]:.0f} us (p50 {rt_ipc["us_p50"]:.0f})')
    results: dict[str, Any] = {'round_trip_in_process_2': rt_in, 'round_trip_ipc_2': rt_ipc, 'runs': {}}
    for scene in a.scenes:
        for mode in a.modes:
            composed = mode
            rt = rt_in if mode != 'separate' else rt_ipc
            rows = []
            # start-up CPU (imports, kernel load, discovery) of a run of 50 exchanges, taken
            # off every run: total CPU per exchange = (cpu_s - base cpu_s) / (steps - base steps);
            # the cheaper of two such runs, since the first may compile what the kernel cache
            # lacks (a first base run once took 9 s more CPU than the 5 s run itself)
            base = min((run_once(scene, composed, 50 * a.exchange_step, a.exchange_step)
                        for _ in range(2)), key=lambda r: r['cpu_s'])
            for i in range(a.runs):
                row = run_once(scene, composed, a.duration, a.exchange_step)
                row['ratio'] = row['overhead_us'] / rt['us_mean']
                row['total_cpu_us'] = (row['cpu_s'] - base['cpu_s']) / (row['steps'] - base['steps']) * 1e6
                rows.append(row)
                print(f'{scene:14s} {mode:12s} run {i + 1}: real-time factor {row["rtf"]:.3g}, '
                      f'{row["wall_us"]:.0f} us/exchange (integration {row["integration_us"]:.0f}, '
                      f'overhead {row["overhead_us"]:.0f} = {row["ratio"]:.2f}x the {mode} 2-peer '
                      f'round trip {rt["us_mean"]:.0f} us; CPU per exchange: coupling process '
                      f'{row["cpu_us"]:.0f} us, all processes {row["total_cpu_us"]:.0f} us)',
                      flush=True)
            med = statistics.median(r['rtf'] for r in rows)
            print(f'{scene:14s} {mode:12s} median real-time factor {med:.3g}', flush=True)
            results['runs'][f'{scene}/{mode}'] = rows
    load1 = os.getloadavg()
    print(f'load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}')
    results['loadavg'] = [load0, load1]
    if a.json is not None:
        a.json.write_text(json.dumps(results, indent=2))


if __name__ == '__main__':
    main()
