"""Paper 001's robust self-triggered MPC: re-export of :mod:`train_envs.controllers.tube`."""

from train_envs.controllers.tube.rsmpc import RobustSelfTriggeredMPC
from train_envs.controllers.tube.tube_mpc import TubeMPC

__all__ = ["RobustSelfTriggeredMPC", "TubeMPC"]
