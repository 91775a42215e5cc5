"""The env's reward: weighted per-objective costs of one env step.

Over the control steps ``k`` of one env step (state at the start of each control period,
as :class:`train_envs.simulation.ClosedLoop` records it, period ``dt``)::

    tracking    = Σ_k (v_ref,k − v_k)² dt                    [(m/s)² s]
    jerk        = Σ_k ((a_k − a_{k−1}) / dt)² dt              [(m/s³)² s]
    energy      = ΔE,  E = (W_traction / η_t − η_r W_brake) / 3.6e6   [kWh]
    violation   = (Σ_k max(v_k − v_limit,k, 0) + Σ_k saturated_k) dt
                  + atp + coupler + overrun      (the safety terms below)
    stop        = |s − s_stop|                  (last env step only)  [m]
    punctuality = |t − t_scheduled| / 10 s      (last env step only)

The safety cost of the step (``info["cost"]``, Safety-Gymnasium's convention: a float
≥ 0 per step, 0 when the step was safe) is the sum of its components
(``info["cost_components"]``), from the runner's supervision columns
(:mod:`train_envs.simulation.supervision`)::

    overspeed = Σ_k max(v_k − v_limit,k, 0) dt      [m]
    atp       = Σ_k atp_brake_k dt                  [s]  (time under the ATP brake)
    coupler   = Σ_k coupler_excess_k dt             [s]  (fraction beyond the limits)
    overrun   = increase of max(s − s_stop − window, 0) over the step  [m]

Summed over an episode it equals the ``safety_cost`` episode metric.

``reward = −Σ_i w_i c_i`` in the order of :data:`OBJECTIVES`. ``a_{k−1}`` of the first
control step of an env step is the last one of the previous env step (at reset: the
plant's acceleration). A NaN speed counts as overspeed.
"""

from __future__ import annotations

from collections.abc import Mapping

from train_envs.scenarios import Scenario
from train_envs.simulation import ClosedLoop
from train_envs.simulation.supervision import overrun_m

#: the reward's objectives, in the order of the weighted sum and of ``info["objectives"]``
OBJECTIVES = ("tracking", "jerk", "energy", "violation", "stop", "punctuality")

#: the default weight of each objective
DEFAULT_WEIGHTS: dict[str, float] = {
    "tracking": 1.0,
    "jerk": 0.05,
    "energy": 0.0,
    "violation": 10.0,
    "stop": 5.0,
    "punctuality": 1.0,
}

#: the recorded columns a step's costs read (and ``coupler_excess`` on multi-car runs)
STEP_COLUMNS = ("v_mps", "a_mps2", "v_ref_mps", "v_limit_mps", "saturated", "atp_brake")

#: the components of the safety cost ``info["cost"]``, in order
COST_COMPONENTS = ("overspeed", "atp", "coupler", "overrun")


class TuningReward:
    """The costs :data:`OBJECTIVES` of an env step and their weighted sum.

    Args:
        weights: objective -> weight; objectives it omits weigh 0.
    """

    def __init__(self, weights: Mapping[str, float]) -> None:
        self.weights = {k: float(weights.get(k, 0.0)) for k in OBJECTIVES}
        self._w = tuple(self.weights[k] for k in OBJECTIVES)

    def bind(self, scenario: Scenario, loop: ClosedLoop) -> None:
        """Start an episode on ``loop`` (just reset) running ``scenario``."""
        self._loop = loop
        self._dt = scenario.dt_ctrl_s
        self._s_stop = scenario.s_stop_m
        self._t_sched = scenario.scheduled_time_s
        tr = scenario.train
        self._eta_t, self._eta_r = tr.traction_efficiency, tr.regen_efficiency
        self._a_prev = loop.plant.accel
        self._energy_prev = 0.0
        self._window = scenario.stop_window()
        self._coupled = loop.plant.n > 1
        self._names = STEP_COLUMNS + (("coupler_excess",) if self._coupled else ())
        self._overrun = overrun_m(loop.plant.s, self._s_stop, self._window)
        #: the safety cost components of the last step (see the module docstring)
        self.safety: dict[str, float] = dict.fromkeys(COST_COMPONENTS, 0.0)

    def costs(self, k0: int, final: bool) -> dict[str, float]:
        """The costs of the control steps ``k0 ..`` ``loop.k − 1``; ``final``: the
        episode ends with them (adds ``stop`` and ``punctuality``)."""
        loop = self._loop
        dt = self._dt
        k1 = loop.k
        j0 = k0 - 1 if k0 > 0 else 0  # one row more: the previous step's last row
        rows = loop.columns(j0, k1, self._names)
        i0 = k0 - j0
        # a handful of rows: Python floats (see docs/design/envs.md)
        v = rows["v_mps"].tolist()[i0:]
        a_all = rows["a_mps2"].tolist()
        tracking = 0.0
        for x, y in zip(rows["v_ref_mps"].tolist()[i0:], v, strict=True):
            e = x - y
            tracking += e * e
        tracking *= dt
        prev = a_all[0] if i0 else self._a_prev  # the previous row holds a_prev
        jerk = 0.0
        for x in a_all[i0:]:
            jk = (x - prev) / dt
            jerk += jk * jk
            prev = x
        jerk *= dt
        self._a_prev = prev
        lim, sat = rows["v_limit_mps"].tolist()[i0:], rows["saturated"].tolist()[i0:]
        over = 0.0
        if any(sat) or not all(x - y <= 0.0 for x, y in zip(v, lim, strict=True)):
            # overspeed (NaN counts) plus saturated steps
            d = [x - y for x, y in zip(v, lim, strict=True)]
            over = sum(e if not e <= 0.0 else 0.0 for e in d)
            violation = (over + sum(sat)) * dt
        else:  # the usual case, no overspeed, no saturation (NaN takes the branch above)
            violation = 0.0
        p = loop.plant
        safety = self._safety(rows, i0, over * dt, p.s)
        extra = safety["atp"] + safety["coupler"] + safety["overrun"]
        if extra:
            violation += extra
        e_now = (p.work_traction_J / self._eta_t - self._eta_r * p.work_brake_J) / 3.6e6
        energy = e_now - self._energy_prev
        self._energy_prev = e_now
        stop = punctuality = 0.0
        if final:
            if self._s_stop is not None:
                stop = abs(p.s - self._s_stop)
            if self._t_sched is not None:
                punctuality = abs(p.t - self._t_sched) / 10.0
        return {
            "tracking": tracking,
            "jerk": jerk,
            "energy": energy,
            "violation": violation,
            "stop": stop,
            "punctuality": punctuality,
        }

    def _safety(
        self, rows: Mapping[str, object], i0: int, overspeed: float, s_now: float
    ) -> dict[str, float]:
        """The safety cost components of the step (stored in :attr:`safety`)."""
        dt = self._dt
        atp = sum(rows["atp_brake"].tolist()[i0:]) * dt  # type: ignore[attr-defined]
        coupler = 0.0
        if self._coupled:
            coupler = sum(rows["coupler_excess"].tolist()[i0:]) * dt  # type: ignore[attr-defined]
        now = overrun_m(s_now, self._s_stop, self._window)
        overrun = now - self._overrun if now > self._overrun else 0.0
        self._overrun = max(self._overrun, now)
        self.safety = {"overspeed": overspeed, "atp": atp, "coupler": coupler, "overrun": overrun}
        return self.safety

    def cost(self) -> float:
        """The safety cost of the last step: the sum of :attr:`safety` (≥ 0)."""
        c = self.safety
        return c["overspeed"] + c["atp"] + c["coupler"] + c["overrun"]

    def reward(self, costs: Mapping[str, float]) -> float:
        """``−Σ_i w_i c_i`` over :data:`OBJECTIVES`, summed in that order."""
        w = self._w
        return -(
            0.0
            + w[0] * costs["tracking"]
            + w[1] * costs["jerk"]
            + w[2] * costs["energy"]
            + w[3] * costs["violation"]
            + w[4] * costs["stop"]
            + w[5] * costs["punctuality"]
        )
