"""Compatibility re-export of the shared pieces of the cvj_ros nodes: parameters, stamps, diagnostics, the main loop.

Parameters are declared from :class:`ParamSpec` lists with a full
``ParameterDescriptor`` (description with unit, FloatingPointRange / IntegerRange,
read_only) and validated on start; a bad value raises :class:`ParameterError` whose
message starts with the parameter name, and :func:`run_node` turns it into one line on
stderr and exit status 2 (runtime errors exit 1, a normal end 0).

Stamps are integer nanoseconds of simulated time everywhere (t_k = k * h_ns), so the
lockstep handshake compares stamps exactly and runs are reproducible bit for bit.
"""
from __future__ import annotations

# Each concern lives in its own module: parameters, diagnostics (stamps + /diagnostics),
# cdr (encoders), executor (CvjNode, spin, run_node), torque_responder.
from cvj_ros.nodes.parameters import (  # noqa: F401
    EXIT_OK,
    EXIT_PARAMETER,
    EXIT_RUNTIME,
    NS_PER_S,
    ParamSpec,
    ParameterError,
    _rclpy_reason,
    declare_parameters,
    inertia_names,
    load_scene_param,
    load_yaml_mapping,
    parse_assignments,
    scene_dict,
    scene_seed)
from cvj_ros.nodes.diagnostics import (  # noqa: F401
    ERROR,
    OK,
    STALE,
    WARN,
    diag_array,
    diag_status,
    level_for,
    ns_to_stamp,
    stamp_to_ns)
from cvj_ros.nodes.cdr import (  # noqa: F401
    ClockEncoder,
    JointStateEncoder,
    WrenchStampedEncoder,
    _CDR_HEADER,
    _LE_DOUBLE,
    _LE_UINT32,
    _STAMP,
    _align,
    _cdr_string,
    _self_check,
    decode_wrench_header_torque_z,
    decode_wrench_stamp_torque_z)
from cvj_ros.nodes.executor import (  # noqa: F401
    CvjNode,
    _run_node,
    flush_publishers,
    make_executor,
    run_node,
    spin_until_done)
from cvj_ros.nodes.torque_responder import (  # noqa: F401
    TorqueResponder,
    load_torque_series_file)
