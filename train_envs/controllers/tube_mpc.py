"""Paper 001's tube robust MPC: re-exports of :mod:`train_envs.controllers.tube`.

The public names are those of :data:`train_envs.controllers.tube.__all__`; the row
indices and the private helpers of the package's modules (``_cache_put``,
``_min_reduce``, ``_single_thread_blas``, ...) and the aliases ``_Explicit``,
``_Problem``, ``_StageData`` and ``_BIG`` stay importable from here.
"""

from typing import Any

from train_envs.controllers import tube as _tube
from train_envs.controllers.tube import *  # noqa: F403
from train_envs.controllers.tube import closed_form as _closed_form
from train_envs.controllers.tube import model as _model
from train_envs.controllers.tube import problem as _problem
from train_envs.controllers.tube import stage as _stage
from train_envs.controllers.tube import tube_mpc as _tube_mpc

__all__ = list(_tube.__all__)

#: private alias -> (home module, name there)
_ALIASES = {
    "_Explicit": (_closed_form, "ClosedForm"),
    "_Problem": (_problem, "TubeProblem"),
    "_StageData": (_stage, "StageData"),
    "_BIG": (_problem, "BIG"),
}


def __getattr__(name: str) -> Any:
    """A private helper of the package, looked up in its home module."""
    if name in _ALIASES:
        module, attr = _ALIASES[name]
        return vars(module)[attr]
    for module in (_closed_form, _model, _tube_mpc):
        if name.startswith("_") and name in vars(module):
            return vars(module)[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
