"""Single-point train whose traction/braking actuator is a first-order lag with dead time.

Paper 001 (Liu, Xun, Gao, Yin 2022), eq. (1)–(8)::

    A_c(s) = e^{−T_d s} / (τ s + 1) · A_t(s)                      (1)
    ȧ_c(t) = −a_c(t)/τ + c u(t − T_d)/τ                           (2), (4), (8)
    v̇(t)  = a_c(t) − a_r(t),   a_r = a_w(v) + a_g(s)              (5)–(8)
    ṡ(t)  = v(t)

with a_w the Davis resistance per unit mass (7) and a_g the gradient/curve resistance
(6). Here the command is the force ``F_cmd = M(1+ρ) c u`` [N], saturated by the
traction/braking envelope of the train (constant force up to the base speed, then
power-limited), so a_c = F/(M(1+ρ)); everything else is the n = 1 case of
:class:`train_envs.plants.multi_car.TrainPlant`, which integrates the lag exactly and
realises the dead time with a buffer of ``T_d / dt_sim_s`` sub-steps.
"""

from __future__ import annotations

from train_envs.plants.actuator import ActuatorParams
from train_envs.plants.multi_car import TrainPlant
from train_envs.trains import TrainParams


class PointMassTrain(TrainPlant):
    """Single-point train (``n_cars = 1``) with lag + dead-time actuator (paper 001)."""

    def __init__(
        self,
        train: TrainParams,
        gradient_permil=None,
        *,
        tau_s: float = 0.4,
        dead_time_s: float = 1.0,
        dt_sim_s: float = 0.01,
        disturbances=(),
        davis_variation=None,
    ) -> None:
        actuator = ActuatorParams(
            order=1 if tau_s > 0 else 0, tau_s=tau_s or 0.4, dead_time_s=dead_time_s
        )
        super().__init__(
            train,
            gradient_permil,
            n_cars=1,
            actuator=actuator,
            dt_sim_s=dt_sim_s,
            disturbances=disturbances,
            davis_variation=davis_variation,
            input_mode="total",
        )
