"""The one closed-loop runner: plant + line + reference + controller, step by step.

:class:`ClosedLoop` is used by everything that runs a train: :func:`simulate` (a whole
episode → DataFrame + metrics), :func:`train_envs.simulation.evaluation.evaluate_params`
(parameters over seeds → metrics table), and the Gymnasium envs (one env step = a few
control steps, with parameters changed in between). It records one row per control
period into preallocated arrays, so a failure part-way loses nothing:
:class:`SimulationError` carries the partial result. Every run is supervised
(:mod:`.supervision`: ATP brake above the limit plus a margin, safety columns).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from train_envs.controllers.base import Controller, Observation
from train_envs.metrics import episode_metrics
from train_envs.plants.multi_car import _np_sum
from train_envs.scenarios import Scenario, build_plant, gradient_lookup
from train_envs.simulation.supervision import (
    ATP,
    Supervision,
    coupler_excess,
    overrun_m,
    permitted_speed_fn,
)

#: the runner's safety columns (see :mod:`.supervision`; the last one: multi-car runs)
SAFETY_COLUMNS = ("atp_brake", "overspeed_mps", "overrun_m", "coupler_excess")

#: controller info keys copied into the DataFrame when present (numeric only)
INFO_COLUMNS = (
    "solve_time_s",
    "iterations",
    "slack_max",
    "fallback",
    "status_val",
    "triggered",
    "alpha",
    "h_c",
    "J",
    "w_hat",
)


@dataclass
class SimulationResult:
    """A finished (or partial) closed-loop run."""

    df: pd.DataFrame
    metrics: dict[str, float]
    scenario: str
    controller: str
    params: dict[str, float] = field(default_factory=dict)
    seed: int | None = None
    wall_time_s: float = 0.0
    error: str | None = None

    def metrics_frame(self) -> pd.DataFrame:
        return pd.DataFrame(
            [{"scenario": self.scenario, "controller": self.controller, **self.metrics}]
        )


class SimulationError(RuntimeError):
    """Raised when a run fails part-way; ``partial`` holds everything computed so far."""

    def __init__(self, message: str, partial: SimulationResult) -> None:
        super().__init__(message)
        self.partial = partial


class ClosedLoop:
    """Stepwise closed loop of one scenario and one controller.

    Usage::

        loop = ClosedLoop(scenario, controller)
        loop.reset(seed=0)
        while not loop.done:
            loop.step()
        result = loop.result()
    """

    def __init__(
        self,
        scenario: Scenario,
        controller: Controller,
        supervision: Supervision | None = None,
    ) -> None:
        self.scenario = scenario
        self.controller = controller
        self.supervision = Supervision() if supervision is None else supervision
        self.dt = scenario.dt_ctrl_s
        self.n_max = int(math.ceil(scenario.t_max_s / self.dt)) + 2
        self.plant = None
        self.seed: int | None = None

    # ------------------------------------------------------------------ setup
    def reset(self, seed: int | None = None, *, scenario: Scenario | None = None) -> Observation:
        if scenario is not None:
            self.scenario = scenario
            self.dt = scenario.dt_ctrl_s
            self.n_max = int(math.ceil(scenario.t_max_s / self.dt)) + 2
        sc = self.scenario
        self.seed = seed
        rng = np.random.default_rng(seed)
        self.plant = build_plant(sc, rng)
        self.ctx = sc.control_context()
        self.controller.reset(self.ctx)
        self.u_prev = initial_commands(sc, self.ctx.n_inputs)
        self.k = 0
        self._moved = sc.v0_mps > 0.1
        self.done = False
        self.terminated = False
        self.truncated = False
        self.atp = ATP(self.supervision, sc)
        # the per-step look-ups, bound once per episode
        self._limit_at = permitted_speed_fn(sc)
        self._gradient_at = gradient_lookup(sc.track).at
        self._window = sc.stop_window()
        cp = sc.train.coupler
        self._coupler_lim = (cp.max_force_N, cp.max_deformation_m)
        self._unsafe = False
        #: what ended the episode under ``end_on_violation`` (``None``: no violation)
        self.safety_end: str | None = None
        self._alloc()
        # (t, s, v, a) of the plant state it was read from (see _lead)
        self._lead_z: np.ndarray | None = None
        self._lead_val: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._t_wall = time.perf_counter()
        self.last_info: Mapping[str, Any] = {}
        return self.observe()

    def _alloc(self) -> None:
        n = self.n_max
        names = record_columns(self.plant.n)
        # one row per control period, in column order; the rows are appended to a list
        # (cheap per step) and moved into the preallocated table when columns are read.
        # Column-major, so that every column is a contiguous array.
        self._data = np.full((n, len(names)), np.nan, order="F")
        self._cols: dict[str, np.ndarray] = {name: self._data[:, j] for j, name in enumerate(names)}
        self._rows: list[tuple[float, ...]] = []
        self._rows_k0 = 0  # control step of self._rows[0]
        self._info_cols: dict[str, np.ndarray] = {}

    def _flush(self) -> None:
        """Move the rows recorded since the last flush into the column table."""
        rows = self._rows
        if rows:
            k0 = self._rows_k0
            self._data[k0 : k0 + len(rows)] = rows
            self._rows_k0 = k0 + len(rows)
            self._rows = []

    def _lead(self) -> tuple[float, float, float, float]:
        """``(t, s, v, a)`` of the plant now, computed once per plant state.

        Every plant step (and reset) replaces the state array ``plant.z``, so its
        identity keys the cache (the reference held here keeps it from being reused).
        """
        p = self.plant
        z = p.z
        if z is not self._lead_z:
            self._lead_val = p._lead_state()
            self._lead_z = z
        return self._lead_val

    def observe(self) -> Observation:
        p = self.plant
        t, s, v, a = self._lead()
        return Observation(
            t_s=t,
            s_m=s,
            v_mps=v,
            a_mps2=a,
            u_prev_N=self.u_prev.copy(),
            positions_m=p.positions,
            speeds_mps=p.speeds,
            forces_N=p.forces,
        )

    # ------------------------------------------------------------------- step
    def step(self, u: np.ndarray | None = None) -> Mapping[str, Any]:
        """Advance one control period with the controller's command (or ``u`` if given)."""
        if self.done:
            raise RuntimeError("episode is over: call reset()")
        if u is None:
            obs = self.observe()
            u, info = self.controller.compute(obs)
            state = (obs.t_s, obs.s_m, obs.v_mps, obs.a_mps2)
            u_N = _total(obs.forces_N)
        else:
            info = {}
            state = self._lead()
            u_N = None
        u = np.asarray(u, dtype=float).reshape(-1)
        if not (math.isfinite(u[0]) if u.size == 1 else all(map(math.isfinite, u.tolist()))):
            raise ValueError(f"controller {self.controller.name} returned a non-finite command {u}")
        limit = self._limit_at(state[1])
        brake = self.atp.command(state[2], limit)
        if brake is not None:  # the ATP overrides the command
            u = np.array([brake]) if self.ctx.n_inputs == 1 else brake * self.plant.share
        self.last_info = info
        self._record(state, u_N, u, info, limit, brake is not None)
        self.plant.step(u if u.size > 1 else u[0], self.dt)
        self.u_prev = u
        self.k += 1
        self._check_done()
        return info

    def _record(
        self,
        state: tuple[float, float, float, float],
        u_N: float | None,
        u: np.ndarray,
        info: Mapping[str, Any],
        limit: float,
        atp: bool,
    ) -> None:
        """Append the row of control step ``k``: the observed state, references, command,
        the safety columns (``limit``: the permitted speed, ``atp``: the ATP brakes)."""
        k, sc, p = self.k, self.scenario, self.plant
        t, s, v, a = state
        ref = sc.reference
        n = p.n
        if u_N is None:  # the observation's actual force, read from the plant
            u_N = p.force_total
        ul = u.tolist()
        row = (
            t,
            s,
            v,
            a,
            ref.v_ref(t, s),
            ref.s_ref(t),
            limit,
            self._gradient_at(s),
            _np_sum(ul),  # float(np.sum(u))
            u_N,
            p.work_traction_J,
            p.work_brake_J,
            float(p.saturated),
        )
        d = v - limit
        over = d if d > 0.0 else 0.0
        safety = (float(atp), over, overrun_m(s, sc.s_stop_m, self._window))
        if n > 1:
            per_car = ul if u.size == n else (u.sum() * p.share).tolist()
            f, q = p._coupler_extremes()
            exc = coupler_excess(f, q, *self._coupler_lim)
            row = (*row, *per_car, f, q, *safety, exc)
        else:
            exc = 0.0
            row = (*row, *safety)
        self._unsafe = atp or exc > 0.0 or d > self.supervision.margin_mps
        if self._rows_k0 + len(self._rows) != k:
            # a plant step failed after this row was recorded: row k is recorded again
            self._flush()
            self._rows_k0 = k
        self._rows.append(row)
        if info:
            for key in INFO_COLUMNS:
                if key in info:
                    col = self._info_cols.get(key)
                    if col is None:
                        col = self._info_cols[key] = np.full(self.n_max, np.nan)
                    col[k] = float(info[key])

    def _check_done(self) -> None:
        sc, p = self.scenario, self.plant
        t, s, v, _ = self._lead()  # (the next observation reads the same, cached)
        if not self._moved and v > 0.1:
            self._moved = True
        if sc.s_stop_m is not None:
            if p.stopped and self._moved:
                self.terminated = True
            elif s > sc.s_stop_m + sc.overrun_m:
                self.terminated = True
        elif t >= sc.t_max_s - 1e-9:
            self.terminated = True
        if self.supervision.end_on_violation and not self.terminated:
            if self._unsafe:
                self.terminated, self.safety_end = True, "overspeed or coupler beyond limits"
            elif overrun_m(s, sc.s_stop_m, self._window) > 0.0:
                self.terminated, self.safety_end = True, "overrun beyond the stopping window"
        if not self.terminated and (t >= sc.t_max_s - 1e-9 or self.k >= self.n_max - 1):
            self.truncated = True
        self.done = self.terminated or self.truncated

    def columns(
        self, k0: int, k1: int, names: Sequence[str] | None = None
    ) -> dict[str, np.ndarray]:
        """Views of the recorded columns (all, or ``names``) for control steps
        ``k0 .. k1-1`` (no copy)."""
        self._flush()
        cols = self._cols
        if names is None:
            return {name: arr[k0:k1] for name, arr in cols.items()}
        return {name: cols[name][k0:k1] for name in names}

    # ---------------------------------------------------------------- results
    def arrays(self) -> dict[str, np.ndarray]:
        """The columns of :meth:`dataframe` as arrays (no pandas): rows so far + final row."""
        k = self.k
        self._flush()
        cols = {**self._cols, **self._info_cols}
        if not (k > 0 and self.plant is not None):
            return {name: arr[:k].copy() for name, arr in cols.items()}
        obs = self.observe()
        p = self.plant
        coupler = (*p._coupler_extremes(), *self._coupler_lim) if p.n > 1 else None
        last = final_row(
            self.scenario, self._limit_at, self._gradient_at, self._window,
            (obs.t_s, obs.s_m, obs.v_mps, obs.a_mps2), float(np.sum(self.u_prev)),
            float(np.sum(obs.forces_N)), p.work_traction_J, p.work_brake_J, coupler,
        )  # fmt: skip
        out = {}
        for name, arr in cols.items():
            a = np.empty(k + 1)
            a[:k] = arr[:k]
            a[k] = last.get(name, np.nan)
            out[name] = a
        return out

    def dataframe(self) -> pd.DataFrame:
        """Rows recorded so far, plus a final row with the state after the last step."""
        return pd.DataFrame(self.arrays())

    def metrics(self, df: pd.DataFrame | None = None) -> dict[str, float]:
        return scenario_metrics(self.scenario, self.arrays() if df is None else df)

    def result(self, error: str | None = None) -> SimulationResult:
        df = self.dataframe()
        metrics = self.metrics(df) if len(df) else {}
        return SimulationResult(
            df=df,
            metrics=metrics,
            scenario=self.scenario.name,
            controller=self.controller.name,
            params=self.controller.get_params(),
            seed=self.seed,
            wall_time_s=time.perf_counter() - self._t_wall,
            error=error,
        )


def record_columns(n_cars: int) -> list[str]:
    """The runner's recorded columns of a train of ``n_cars`` cars, in table order (the
    info columns of :data:`INFO_COLUMNS` follow where the controller gives them)."""
    names = [
        "t_s",
        "s_m",
        "v_mps",
        "a_mps2",
        "v_ref_mps",
        "s_ref_m",
        "v_limit_mps",
        "gradient_permil",
        "u_cmd_N",
        "u_N",
        "work_traction_J",
        "work_brake_J",
        "saturated",
    ]
    if n_cars > 1:
        names += [f"u{i + 1}_cmd_N" for i in range(n_cars)]
        names += ["coupler_force_max_N", "coupler_def_max_m"]
    names += list(SAFETY_COLUMNS) if n_cars > 1 else list(SAFETY_COLUMNS[:3])
    return names


def initial_commands(sc: Scenario, n_inputs: int) -> np.ndarray:
    """The command ``u_prev`` an episode starts from, ``n_inputs`` entries (the
    scenario's initial command, spread evenly where it has another size)."""
    u = np.asarray(sc.initial_command(), float).reshape(-1)
    if u.size != n_inputs:
        u = np.full(n_inputs, u.sum() / n_inputs)
    return u


def final_row(
    sc: Scenario,
    limit_at: Callable[[float], float],
    gradient_at: Callable[[float], float],
    window_m: float,
    state: tuple[float, float, float, float],
    u_cmd_N: float,
    u_N: float,
    work_traction_J: float,
    work_brake_J: float,
    coupler: tuple[float, float, float, float] | None = None,
) -> dict[str, float]:
    """The last row of a run's columns (:meth:`ClosedLoop.arrays`): the state ``(t, s,
    v, a)`` after the last step, the references, limit and gradient there, the last
    command's total ``u_cmd_N``, the actual force ``u_N``, the work; ``coupler``:
    ``(F, q, F_max, q_max)`` of a multi-car train (its ``coupler_excess``). The
    columns it leaves out are NaN in that row."""
    t, s, v, a = state
    limit = limit_at(s)
    last = dict(
        t_s=t,
        s_m=s,
        v_mps=v,
        a_mps2=a,
        v_ref_mps=sc.reference.v_ref(t, s),
        s_ref_m=sc.reference.s_ref(t),
        v_limit_mps=limit,
        gradient_permil=gradient_at(s),
        u_cmd_N=u_cmd_N,
        u_N=u_N,
        work_traction_J=work_traction_J,
        work_brake_J=work_brake_J,
        saturated=0.0,
        atp_brake=0.0,
        overspeed_mps=max(v - limit, 0.0),
        overrun_m=overrun_m(s, sc.s_stop_m, window_m),
    )
    if coupler is not None:
        last["coupler_excess"] = coupler_excess(*coupler)
    return last


def scenario_metrics(
    sc: Scenario, columns: pd.DataFrame | Mapping[str, np.ndarray]
) -> dict[str, float]:
    """:func:`~train_envs.metrics.episode_metrics` of a run's columns on scenario ``sc``."""
    tr = sc.train
    return episode_metrics(
        columns,
        dt_s=sc.dt_ctrl_s,
        s_stop_m=sc.s_stop_m,
        scheduled_time_s=sc.scheduled_time_s,
        traction_efficiency=tr.traction_efficiency,
        regen_efficiency=tr.regen_efficiency,
        du_max_Nps=sc.du_max_Nps,
    )


def _total(x: np.ndarray) -> float:
    """``float(np.sum(x))`` (the element itself for one element)."""
    return float(x[0]) if len(x) == 1 else float(np.sum(x))


def simulate(
    scenario: Scenario | str,
    controller: Controller | str,
    *,
    seed: int | None = 0,
    params: Mapping[str, float] | None = None,
    supervision: Supervision | None = None,
) -> SimulationResult:
    """Run one closed-loop episode and return its DataFrame and metrics.

    ``scenario`` and ``controller`` may be names (see ``train-envs list``);
    ``supervision``: the ATP settings (default :class:`Supervision`, ATP on). If the run
    fails part-way, :class:`SimulationError` is raised with the partial result attached.
    """
    from train_envs.controllers import make_controller
    from train_envs.scenarios import get_scenario

    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    ctrl = make_controller(controller, sc) if isinstance(controller, str) else controller
    if params:
        ctrl.set_params(**params)
    loop = ClosedLoop(sc, ctrl, supervision)
    loop.reset(seed=seed)
    run_to_end(loop)
    return loop.result()


def run_to_end(loop: ClosedLoop, max_steps: int | None = None, *, partial: bool = True) -> None:
    """Step a reset ``loop`` until its episode is over, or until ``max_steps`` control
    steps have run in total (a step cap; ``None``: the scenario's own end).

    A failure part-way raises :class:`SimulationError` with the partial result attached
    (``partial=False``: the original exception, as an env step raises it).
    """
    try:
        if max_steps is None:
            while not loop.done:
                loop.step()
        else:
            while not loop.done and loop.k < max_steps:
                loop.step()
    except Exception as exc:  # keep what was computed
        if not partial:
            raise
        partial = loop.result(error=f"{type(exc).__name__}: {exc}")
        raise SimulationError(
            f"simulation failed at t={loop.plant.t:.2f} s: {exc}", partial
        ) from exc
