"""Single controllers as the batched controller of :class:`~.batch.BatchLoop`.

:class:`MemberControllers` gives the lockstep runner every single-input controller
that has no array law of its own (the linear, tube and self-triggered MPCs, the
adaptive MPC, AFSMC, and the PID / Fuzzy-PID / DMC configurations their lockstep twins
do not cover): member ``b``'s command is its own controller's
:meth:`~train_envs.controllers.base.Controller.compute` on the
:class:`~train_envs.controllers.base.Observation` the single runner
(:meth:`~.loop.ClosedLoop.observe`) would hand it, built from the batched plant's
read-outs of that member (a single-car plant: ``positions_m = [s]``, ``speeds_mps =
[v]``, ``forces_N = [F]``). So every member equals its single closed loop bit for bit
(tested); what the members share is the runner's step (the batched plant, the ATP, the
record) and, in the vector env and the tuner's lockstep backend, the env's and the
evaluation's work around it. The control law itself runs member by member.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from train_envs.controllers.base import Controller, Observation
from train_envs.simulation.loop import INFO_COLUMNS

__all__ = ["MemberControllers"]

_NAN = float("nan")


class MemberControllers:
    """B single controllers, one per member, stepped by :class:`~.batch.BatchLoop`.

    Args:
        controllers: member ``b``'s controller at ``b``, each reset on the scenario's
            control context with the member's parameters (its owner's job: the env's
            reset, or :func:`train_envs.envs.batch.evaluate_env_params_batch`).
    """

    #: :class:`~.batch.BatchLoop` hands :meth:`compute` the members' accelerations and
    #: actual forces (what the observation holds beyond the batched laws' inputs)
    needs_plant_state = True

    def __init__(self, controllers: Sequence[Controller]) -> None:
        self.controllers = list(controllers)
        if not self.controllers:
            raise ValueError("MemberControllers needs at least one controller")
        self.B = len(self.controllers)

    def set_params(self, b: int, params: Mapping[str, float]) -> None:
        """Member ``b``'s parameters (its controller's ``set_params``)."""
        self.controllers[b].set_params(**params)

    def reset(self, ix: np.ndarray | None = None) -> None:
        """Start an episode for members ``ix``: nothing to do here, the owner has reset
        each member's controller for its episode (the env's reset in the vector env, a
        fresh controller per member in the lockstep evaluation), as the single runner's
        owner does."""

    def compute(
        self,
        ix: np.ndarray,
        t: np.ndarray,
        s: np.ndarray,
        v: np.ndarray,
        u_prev_N: np.ndarray,
        a: np.ndarray,
        force_N: np.ndarray,
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """One control step of members ``ix`` (times ``t``, positions ``s``, speeds
        ``v``, last commands ``u_prev_N``, accelerations ``a``, actual forces
        ``force_N``, one entry each); returns their commands [N] and the info columns
        of :data:`~.loop.INFO_COLUMNS` any of them gave (NaN where a member gave none,
        as the single runner's record leaves it)."""
        ctrls = self.controllers
        u = np.empty(len(ix))
        infos = []
        rows = zip(
            ix.tolist(), t.tolist(), s.tolist(), v.tolist(), u_prev_N.tolist(), a.tolist(),
            force_N.tolist(), strict=True,
        )  # fmt: skip
        for r, (b, tr, sr, vr, ur, ar, fr) in enumerate(rows):
            obs = Observation(
                t_s=tr,
                s_m=sr,
                v_mps=vr,
                a_mps2=ar,
                u_prev_N=np.array([ur]),
                positions_m=np.array([sr]),
                speeds_mps=np.array([vr]),
                forces_N=np.array([fr]),
            )
            cmd, info = ctrls[b].compute(obs)
            cmd = np.asarray(cmd, dtype=float).reshape(-1)
            if cmd.size != 1:
                raise ValueError(
                    f"controller {ctrls[b].name} returned {cmd.size} commands for a "
                    "one-input scenario"
                )
            u[r] = cmd[0]
            infos.append(info)
        keys = [key for key in INFO_COLUMNS if any(key in info for info in infos)]
        out = {
            key: np.array([float(info[key]) if key in info else _NAN for info in infos])
            for key in keys
        }
        return u, out
