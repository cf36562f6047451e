"""Mode elements (friction clutch, gearbox, brake) of a chain driveline, with stick and slip
solved as modes and transitions located on the stepper's dense output (docs/clutch_gearbox.md).
Pure Python reference; no ROS import."""
from __future__ import annotations

from cvj_ros.physics.hybrid.chain import HybridChain, Mode, SectionState
from cvj_ros.physics.hybrid.commands import CommandSchedule
from cvj_ros.physics.hybrid.elements import Brake, Clutch, Gearbox
from cvj_ros.physics.hybrid.friction import BACKWARD, FORWARD, STUCK, CoulombPack
from cvj_ros.physics.hybrid.simulate import HybridResult, HybridSimulation, ModeEvent

__all__ = ['BACKWARD', 'FORWARD', 'STUCK', 'Brake', 'Clutch', 'CommandSchedule', 'CoulombPack',
           'Gearbox', 'HybridChain', 'HybridResult', 'HybridSimulation', 'Mode', 'ModeEvent',
           'SectionState']
