"""The linear-MPC QP engine: one quadratic program per sampling instant, solved by OSQP.

It knows nothing about trains; every model-predictive controller of the library is
built on :class:`LinearMPC`.  Modules:

* :mod:`~train_envs.mpc.linear_mpc` -- :class:`LinearMPC` (construction, ``solve``);
* :mod:`~train_envs.mpc.description` -- argument checks, constraint groups;
* :mod:`~train_envs.mpc.layout` -- variable/row layout, parameter vector, data loading;
* :mod:`~train_envs.mpc.assembly` -- ``P``, ``q``, ``A`` and the per-step data map;
* :mod:`~train_envs.mpc.bounds` -- base and per-call bounds, the safe first move;
* :mod:`~train_envs.mpc.unconstrained` -- the unconstrained optimum and its maps;
* :mod:`~train_envs.mpc.recovery` -- rescue, exact refinement, fallback;
* :mod:`~train_envs.mpc.osqp_backend` -- the only module that touches OSQP;
* :mod:`~train_envs.mpc.solution` -- :class:`MPCSolution`;
* :mod:`~train_envs.mpc.design` -- DARE, Lyapunov, ZOH discretisation.

Design notes and measurements: ``docs/design/mpc_engine.md``.
"""

from train_envs.mpc.design import (
    augmented_model,
    augmented_terminal_cost,
    dare_doubling,
    terminal_cost_dare,
    terminal_cost_lyapunov,
    zoh,
)
from train_envs.mpc.linear_mpc import LinearMPC
from train_envs.mpc.solution import MPCSolution
from train_envs.mpc.unconstrained import UnconstrainedAffine, UnconstrainedGain

__all__ = [
    "LinearMPC",
    "MPCSolution",
    "UnconstrainedAffine",
    "UnconstrainedGain",
    "augmented_model",
    "augmented_terminal_cost",
    "dare_doubling",
    "terminal_cost_dare",
    "terminal_cost_lyapunov",
    "zoh",
]
