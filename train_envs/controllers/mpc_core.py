"""The linear-MPC QP engine, re-exported from its home :mod:`train_envs.mpc`.

Kept so that ``from train_envs.controllers.mpc_core import LinearMPC`` (README,
notebooks, user code) keeps working.
"""

from train_envs.mpc.description import (
    _SOFT_GROUPS,
    _check_order,
    _check_penalty_arg,
    _Group,
    _matrix,
    _vector,
    _weight,
)
from train_envs.mpc.design import terminal_cost_dare, terminal_cost_lyapunov
from train_envs.mpc.linear_mpc import LinearMPC
from train_envs.mpc.osqp_backend import (
    _BIG,
    _DEFAULT_OSQP,
    _RENAMED_SETTINGS,
    _RESCUE,
    _SOLVED,
    _SOLVED_INACCURATE,
    _STATUS_EXCEPTION,
    _STATUS_INVALID_INPUT,
    _UNCONSTRAINED,
    _Backend,
)
from train_envs.mpc.solution import MPCSolution
from train_envs.mpc.unconstrained import UnconstrainedAffine, UnconstrainedGain

__all__ = [
    "LinearMPC",
    "MPCSolution",
    "UnconstrainedAffine",
    "UnconstrainedGain",
    "terminal_cost_dare",
    "terminal_cost_lyapunov",
]

# private names kept importable from the old path
_PRIVATE = (
    _BIG,
    _DEFAULT_OSQP,
    _RENAMED_SETTINGS,
    _RESCUE,
    _SOFT_GROUPS,
    _SOLVED,
    _SOLVED_INACCURATE,
    _STATUS_EXCEPTION,
    _STATUS_INVALID_INPUT,
    _UNCONSTRAINED,
    _Backend,
    _Group,
    _check_order,
    _check_penalty_arg,
    _matrix,
    _vector,
    _weight,
)
