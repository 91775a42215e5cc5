"""Single controllers as the batched controller of :class:`~.batch.BatchLoop`.

:class:`MemberControllers` gives the lockstep runner every controller that has no array
law of its own (the linear, tube and self-triggered MPCs, the adaptive MPCs, AFSMC, the
multi-car MPCs, and the PID / Fuzzy-PID / DMC configurations their lockstep twins do
not cover): member ``b``'s command is its own controller's
:meth:`~train_envs.controllers.base.Controller.compute` on the
:class:`~train_envs.controllers.base.Observation` the single runner
(:meth:`~.loop.ClosedLoop.observe`) would hand it, built from the batched plant's
read-outs of that member (a single-car plant: ``positions_m = [s]``, ``speeds_mps =
[v]``, ``forces_N = [F]``; a multi-car plant: its cars' positions, speeds and forces;
with one input per car, the last command and the command are per-car vectors). So
every member equals its single closed loop bit for bit (tested); what the members share
is the runner's step (the batched plant, the ATP, the record) and, in the vector env
and the tuner's lockstep backend, the env's and the evaluation's work around it. The
control law itself runs member by member.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence

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
        cars: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """One control step of members ``ix`` (times ``t``, positions ``s``, speeds
        ``v``, last commands ``u_prev_N``, accelerations ``a``, actual forces
        ``force_N``, one entry each; ``u_prev_N`` one row of ``n_inputs`` each where the
        scenario has several inputs; ``cars``: the positions, speeds and forces of each
        member's cars, one row each, on multi-car members); returns their commands [N]
        (in ``u_prev_N``'s shape) and the info columns of :data:`~.loop.INFO_COLUMNS`
        any of them gave (NaN where a member gave none, as the single runner's record
        leaves it)."""
        ctrls = self.controllers
        per_input = u_prev_N.ndim == 2
        width = u_prev_N.shape[1] if per_input else 1
        u = np.empty(u_prev_N.shape)
        infos = []
        for r, (b, obs) in enumerate(
            zip(ix.tolist(), _observations(t, s, v, u_prev_N, a, force_N, cars), strict=True)
        ):
            cmd, info = ctrls[b].compute(obs)
            cmd = np.asarray(cmd, dtype=float).reshape(-1)
            if cmd.size != width:
                raise ValueError(
                    f"controller {ctrls[b].name} returned {cmd.size} commands for a "
                    f"scenario with {width} input{'s' if width > 1 else ''}"
                )
            u[r] = cmd if per_input else cmd[0]
            infos.append(info)
        keys = [key for key in INFO_COLUMNS if any(key in info for info in infos)]
        out = {
            key: np.array([float(info[key]) if key in info else _NAN for info in infos])
            for key in keys
        }
        return u, out


def _observations(
    t: np.ndarray,
    s: np.ndarray,
    v: np.ndarray,
    u_prev_N: np.ndarray,
    a: np.ndarray,
    force_N: np.ndarray,
    cars: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
) -> Iterator[Observation]:
    """The :class:`Observation` of each member, as :meth:`~.loop.ClosedLoop.observe`
    builds it: the lead car's time, position, speed and acceleration, the last command
    (an array of ``n_inputs``), the cars' positions, speeds and forces (a single car's:
    ``[s]``, ``[v]``, ``[F]``)."""
    lead = zip(t.tolist(), s.tolist(), v.tolist(), a.tolist(), strict=True)
    if u_prev_N.ndim == 2:
        ups: Iterable[np.ndarray] = (row.copy() for row in u_prev_N)
    else:
        ups = (np.array([x]) for x in u_prev_N.tolist())
    if cars is None:  # single cars
        per_car: Iterable[tuple[np.ndarray, ...]] = (
            (np.array([x]), np.array([y]), np.array([f]))
            for x, y, f in zip(s.tolist(), v.tolist(), force_N.tolist(), strict=True)
        )
    else:
        per_car = ((p.copy(), w.copy(), f.copy()) for p, w, f in zip(*cars, strict=True))
    for (tr, sr, vr, ar), up, (pos, spd, frc) in zip(lead, ups, per_car, strict=True):
        yield Observation(
            t_s=tr,
            s_m=sr,
            v_mps=vr,
            a_mps2=ar,
            u_prev_N=up,
            positions_m=pos,
            speeds_mps=spd,
            forces_N=frc,
        )
