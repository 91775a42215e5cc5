"""Paper 001's tube robust MPC (``rmpc``) and robust self-triggered MPC (``rsmpc``).

Modules: :mod:`.model` (stopping model, tube feedback, terminal weight, tightening),
:mod:`.settings` (structural options), :mod:`.stage` (the per-step stage vector),
:mod:`.problem` (one QP of the family), :mod:`.closed_form` (its unconstrained optimum
in closed form), :mod:`.kernels` (sources of the compiled twins), :mod:`.tube_mpc`
(:class:`TubeMPC`), :mod:`.rsmpc` (:class:`RobustSelfTriggeredMPC`).
"""

from train_envs.controllers.tube import model as _model
from train_envs.controllers.tube.model import *  # noqa: F403 (its __all__)
from train_envs.controllers.tube.rsmpc import RobustSelfTriggeredMPC
from train_envs.controllers.tube.settings import DEFAULT_W_BOUND_MPS2, TubeSettings
from train_envs.controllers.tube.tube_mpc import TubeMPC

__all__ = [
    *_model.__all__,
    "DEFAULT_W_BOUND_MPS2",
    "RobustSelfTriggeredMPC",
    "TubeMPC",
    "TubeSettings",
]
