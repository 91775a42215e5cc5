"""The linear-MPC QP engine, re-exported from its home :mod:`train_envs.mpc`.

Kept so that ``from train_envs.controllers.mpc_core import LinearMPC`` (README,
notebooks, user code) keeps working: the public names are those of
:data:`train_envs.mpc.__all__`, and the private helpers of
:mod:`train_envs.mpc.description` and :mod:`train_envs.mpc.osqp_backend` (``_BIG``,
``_Backend``, ``_matrix``, ...) stay importable from here.
"""

from typing import Any

from train_envs import mpc as _mpc
from train_envs.mpc import *  # noqa: F403
from train_envs.mpc import description as _description
from train_envs.mpc import osqp_backend as _osqp_backend

__all__ = list(_mpc.__all__)


def __getattr__(name: str) -> Any:
    """A private helper of the engine, looked up in its home module."""
    for home in (_description, _osqp_backend):
        if name.startswith("_") and name in vars(home):
            return vars(home)[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
