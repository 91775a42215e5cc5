"""Compiled twins of the tube MPC family: re-exports of :mod:`train_envs.controllers.tube`.

The twins are registered in :data:`train_envs._jit.TWINS` as ``"tube.fill_reference"``
and ``"tube.closed_form"`` (sources in :mod:`train_envs.controllers.tube.kernels`);
take them with :func:`train_envs._jit.implementation`.
"""

from __future__ import annotations

from types import SimpleNamespace

from train_envs._jit import enabled, implementation
from train_envs.controllers.tube import closed_form as _closed_form_module  # noqa: F401
from train_envs.controllers.tube import stage as _stage_module  # noqa: F401
from train_envs.controllers.tube.kernels import closed_form_source as _closed_form
from train_envs.controllers.tube.kernels import fill_reference_source as _fill_reference

__all__ = ["kernels"]

_STATE: dict[str, SimpleNamespace | None] = {}


def kernels() -> SimpleNamespace | None:
    """``fill_reference`` and ``closed_form`` compiled, or None (numba missing or
    ``TRAIN_ENVS_NO_JIT=1``)."""
    if "k" not in _STATE:
        _STATE["k"] = (
            SimpleNamespace(
                fill_reference=implementation("tube.fill_reference", compiled_twin=True),
                closed_form=implementation("tube.closed_form", compiled_twin=True),
            )
            if enabled()
            else None
        )
    return _STATE["k"]


_REEXPORTED = (_closed_form, _fill_reference)
