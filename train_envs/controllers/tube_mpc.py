"""Paper 001's tube robust MPC: re-exports of :mod:`train_envs.controllers.tube`."""

from train_envs.controllers.tube.closed_form import ClosedForm as _Explicit
from train_envs.controllers.tube.closed_form import _min_reduce
from train_envs.controllers.tube.model import (
    _CACHE_MAX,
    _FEEDBACK,
    _MODELS,
    _TIGHTENING,
    ROW_DU,
    ROW_S,
    ROW_U,
    ROW_V,
    StoppingModel,
    TubeFeedback,
    _cache_put,
    stopping_model,
    terminal_weight,
    tube_feedback,
    tube_tightening,
)
from train_envs.controllers.tube.problem import BIG as _BIG
from train_envs.controllers.tube.problem import TubeProblem as _Problem
from train_envs.controllers.tube.settings import DEFAULT_W_BOUND_MPS2, TubeSettings
from train_envs.controllers.tube.stage import StageData as _StageData
from train_envs.controllers.tube.tube_mpc import TubeMPC, _single_thread_blas

__all__ = [
    "DEFAULT_W_BOUND_MPS2",
    "StoppingModel",
    "TubeFeedback",
    "TubeMPC",
    "TubeSettings",
    "stopping_model",
    "terminal_weight",
    "tube_feedback",
    "tube_tightening",
]
# (also kept importable here: the row indices and the helpers below)
_REEXPORTED = (
    ROW_DU, ROW_S, ROW_U, ROW_V, _BIG, _CACHE_MAX, _FEEDBACK, _MODELS, _TIGHTENING,
    _Explicit, _Problem, _StageData, _cache_put, _min_reduce, _single_thread_blas,
)
