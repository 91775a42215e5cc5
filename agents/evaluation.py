"""Evaluation harness: RL policies vs tuned parameter sets vs fixed controllers.

Drivers (small dataclasses) say what sets the controller's parameters:

* :class:`PolicyDriver` — a trained SB3 model (with its VecNormalize statistics),
  deterministic actions;
* :class:`ParamsDriver` — a constant action = fixed parameter values (e.g. a tuner's
  selected solution, see :func:`load_params`);
* :class:`ControllerDriver` — a controller with its defaults: the env's own controller
  (``"defaults"`` or its name) through the env, any other controller name through
  the runner's :func:`train_envs.simulation.evaluate_params` on the same scenario and
  episode seed.

:func:`compare` runs every driver on every env case and seed and returns a tidy
DataFrame (``env, driver, seed, scenario, return, env_steps`` and every metric of
:func:`train_envs.metrics.episode_metrics`, whose names carry their units:
``_m``, ``_mps``, ``_s``, ``_kWh``, ...; ``return`` and counts/fractions are unitless).
Identical seeds give identical tables. :func:`summary` gives mean ± std per
(env, driver), :func:`significance` paired Wilcoxon signed-rank tests against a
baseline driver on the same seeds, :func:`overlay_figure` a speed–distance overlay.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd

__all__ = [
    "ControllerDriver",
    "Driver",
    "EnvCase",
    "ParamsDriver",
    "PolicyDriver",
    "compare",
    "format_summary",
    "load_params",
    "metric_columns",
    "overlay_figure",
    "significance",
    "summary",
    "trajectory",
]

#: non-metric columns of :func:`compare`'s table
ID_COLUMNS = ("env", "env_id", "driver", "seed", "scenario")


@dataclass(frozen=True)
class EnvCase:
    """An env to evaluate on: a registered id, its config and the table's label.

    A plain id string stands for ``EnvCase(id)``; ``name`` defaults to the id.
    """

    env_id: str
    config: Mapping[str, Any] = field(default_factory=dict)
    name: str | None = None

    @property
    def label(self) -> str:
        return self.name or self.env_id

    def make(self) -> Any:
        import gymnasium as gym

        from agents.training import check_env_id

        return gym.make(check_env_id(self.env_id), config=dict(self.config))


def _case(c: str | EnvCase) -> EnvCase:
    if isinstance(c, EnvCase):
        return c
    if isinstance(c, str):
        return EnvCase(c)
    raise ValueError(f"env cases must be env id strings or EnvCase, got {c!r}")


class Driver(Protocol):
    """What :func:`compare` needs of a driver."""

    name: str

    def evaluate(self, case: EnvCase, seeds: Sequence[int]) -> pd.DataFrame: ...

    def trajectory(self, case: EnvCase, seed: int) -> tuple[pd.DataFrame, Any]: ...


def _env_rollout(case: EnvCase, action_fn: Any, seed: int) -> tuple[pd.DataFrame, Any]:
    """Run one episode through the env; the closed loop's DataFrame and the scenario."""
    env = case.make()
    try:
        obs, _ = env.reset(seed=int(seed))
        fn = action_fn(env)
        done = False
        while not done:
            obs, _r, term, trunc, _info = env.step(fn(obs))
            done = term or trunc
        base = env.unwrapped
        return base.loop.dataframe(), base.scenario
    finally:
        env.close()


# ---------------------------------------------------------------------- drivers
@dataclass
class PolicyDriver:
    """A trained SB3 model (run folder, ``best/`` or ``.zip``), deterministic actions.

    ``algo`` is read from the run's ``config.json`` (or the saved policy class) when
    omitted; ``name`` defaults to the run folder's name. On the id it was trained on,
    the policy runs in its training env: the run's saved ``env_config`` with the
    case's config merged over it (``train_envs.envs.config.merge``), so policies
    trained in different modes compare in one table.
    """

    path: str | Path
    name: str = ""
    algo: str | None = None
    _policy: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.name:
            p = Path(self.path)
            parts = [x for x in (p.parent.name, p.stem) if x] if p.suffix == ".zip" else [p.name]
            self.name = "policy:" + "/".join(parts)

    def load(self) -> Any:
        """The :class:`agents.training.LoadedPolicy` (loaded once)."""
        if self._policy is None:
            from agents.training import load_policy

            self._policy = load_policy(self.path, self.algo)
        return self._policy

    def _action_fn(self, env: Any) -> Any:
        pol = self.load()
        m = pol.model
        if m.observation_space.shape != env.observation_space.shape:
            raise ValueError(
                f"{self.name}: policy observation shape {m.observation_space.shape} does not "
                f"match the env's {env.observation_space.shape} (same controller needed)"
            )
        if m.action_space.shape != env.action_space.shape:
            raise ValueError(
                f"{self.name}: policy action shape {m.action_space.shape} does not match the "
                f"env's {env.action_space.shape} (same controller / action_params needed)"
            )
        return pol.predict

    def trained_case(self, case: EnvCase) -> EnvCase:
        """``case`` with the policy's training env config under its own config."""
        record = self.load().config
        if record.get("env_id") != case.env_id or not record.get("env_config"):
            return case
        from train_envs.envs.config import merge

        config = merge(dict(record["env_config"]), dict(case.config))
        return EnvCase(case.env_id, config, case.name)

    def evaluate(self, case: EnvCase, seeds: Sequence[int]) -> pd.DataFrame:
        from train_envs.envs import evaluate

        case = self.trained_case(case)
        env = case.make()
        try:
            fn = self._action_fn(env)
        finally:
            env.close()
        return evaluate(check_id(case), fn, seeds=seeds, config=case.config, label=self.name)

    def trajectory(self, case: EnvCase, seed: int) -> tuple[pd.DataFrame, Any]:
        return _env_rollout(self.trained_case(case), self._action_fn, seed)


@dataclass
class ParamsDriver:
    """Constant action = these parameter values (others keep the controller defaults)."""

    name: str
    params: Mapping[str, float]

    def __post_init__(self) -> None:
        bad = {k: v for k, v in self.params.items() if not np.isfinite(float(v))}
        if bad:
            raise ValueError(f"ParamsDriver {self.name}: parameter values must be finite: {bad}")
        self.params = {str(k): float(v) for k, v in self.params.items()}

    def evaluate(self, case: EnvCase, seeds: Sequence[int]) -> pd.DataFrame:
        from train_envs.envs import evaluate

        return evaluate(
            check_id(case), dict(self.params), seeds=seeds, config=case.config, label=self.name
        )

    def trajectory(self, case: EnvCase, seed: int) -> tuple[pd.DataFrame, Any]:
        from train_envs.envs import params_to_action

        def fn(env: Any) -> Any:
            action = params_to_action(env, self.params)
            return lambda _obs: action

        return _env_rollout(case, fn, seed)


@dataclass
class ControllerDriver:
    """A controller with its default parameters.

    ``"defaults"`` or the env's own controller name: the env with its default action
    (so the return is known). Any other controller name: the runner
    (:func:`~train_envs.simulation.evaluate_params`; :func:`simulate` for its
    trajectory) on the scenario and episode seed the env draws for the seed
    (``return``/``env_steps`` are NaN there: the env's reward is defined for its own
    controller's env steps).
    """

    controller: str = "defaults"
    name: str = ""

    def __post_init__(self) -> None:
        from train_envs.controllers import CONTROLLERS, list_controllers

        if self.controller != "defaults" and self.controller not in CONTROLLERS:
            raise ValueError(
                f"ControllerDriver controller must be 'defaults' or one of: "
                f"{', '.join(list_controllers())}; got {self.controller!r}"
            )
        if not self.name:
            self.name = self.controller

    def _own(self, case: EnvCase) -> bool:
        if self.controller == "defaults":
            return True
        env = case.make()
        try:
            return env.unwrapped.config["controller"] == self.controller
        finally:
            env.close()

    def _simulate(self, case: EnvCase, seed: int) -> tuple[Any, Any]:
        from train_envs.simulation import simulate

        scenario, episode_seed = _env_episode(case, seed)
        return simulate(scenario, self.controller, seed=episode_seed), scenario

    def evaluate(self, case: EnvCase, seeds: Sequence[int]) -> pd.DataFrame:
        from train_envs.envs import evaluate
        from train_envs.simulation import evaluate_params

        if self._own(case):
            return evaluate(check_id(case), None, seeds=seeds, config=case.config, label=self.name)
        source = _OtherControllerEpisodes(case, self.controller, name=self.name)
        return evaluate_params(source, seeds=seeds)

    def trajectory(self, case: EnvCase, seed: int) -> tuple[pd.DataFrame, Any]:
        if self._own(case):
            from train_envs.envs import params_to_action

            def fn(env: Any) -> Any:
                action = params_to_action(env, {})
                return lambda _obs: action

            return _env_rollout(case, fn, seed)
        res, sc = self._simulate(case, seed)
        return res.df, sc


def _env_episode(case: EnvCase, seed: int) -> tuple[Any, int]:
    """The scenario and the runner's episode seed the env draws for ``seed``."""
    env = case.make()
    try:
        env.reset(seed=int(seed))
        base = env.unwrapped
        return base.scenario, base.loop.seed
    finally:
        env.close()


class _OtherControllerEpisodes:
    """Episodes of another controller on the env's scenario and episode seed (the
    runner's :class:`~train_envs.simulation.Episodes`, started from the env's draw);
    ``return`` and ``env_steps`` are NaN: the env's reward is its own controller's."""

    def __init__(self, case: EnvCase, controller: str, *, name: str) -> None:
        self.case = case
        self.controller = controller
        self.ids = {"env": check_id(case), "driver": name}
        self.extra = {"return": np.nan, "env_steps": np.nan}
        self.max_steps = None

    def start(self, seed: int, params: Mapping[str, float] | None) -> Any:
        from train_envs.simulation import Episodes

        scenario, episode_seed = _env_episode(self.case, seed)
        return Episodes(scenario, self.controller).start(episode_seed, params)


def check_id(case: EnvCase) -> str:
    from agents.training import check_env_id

    return check_env_id(case.env_id)


# ------------------------------------------------------------------ parameters
def load_params(spec: str | Path) -> tuple[str, dict[str, float]]:
    """(name, parameter values) from a JSON/YAML file or a tuner study.

    ``spec`` is a ``.json``/``.yml``/``.yaml`` file holding ``{name: value}`` (or
    ``{"params": {...}}``), or ``<optuna storage URL>:<study>`` such as
    ``sqlite:///tuning.db:urban004-mowoa`` — the study's selected solution, as
    ``train-envs tune show`` prints it (plus the study's fixed parameters).
    """
    text = str(spec)
    if "://" in text:
        storage, sep, study = text.rpartition(":")
        if not sep or not study or "://" not in storage or study.startswith("/"):
            raise ValueError(
                f"--params study must be '<storage URL>:<study>', e.g. "
                f"'sqlite:///tuning.db:my-study'; got {text!r}"
            )
        return study, _study_params(storage, study)
    path = Path(text)
    if not path.is_file():
        raise ValueError(
            f"--params {text!r}: no such file (expected a .json/.yml/.yaml file or "
            "'sqlite:///file.db:study')"
        )
    if path.suffix.lower() == ".json":
        data = json.loads(path.read_text())
    elif path.suffix.lower() in (".yml", ".yaml"):
        import yaml

        data = yaml.safe_load(path.read_text())
    else:
        raise ValueError(f"--params file {text!r} must end in .json, .yml or .yaml")
    if isinstance(data, Mapping) and isinstance(data.get("params"), Mapping):
        data = data["params"]
    if not isinstance(data, Mapping) or not data:
        raise ValueError(f"--params file {text!r} must hold a mapping of parameter values")
    try:
        values = {str(k): float(v) for k, v in data.items()}
    except (TypeError, ValueError) as exc:
        raise ValueError(f"--params file {text!r}: values must be numbers ({exc})") from exc
    return path.stem, values


def _study_params(storage: str, study: str) -> dict[str, float]:
    import optuna

    from tuners.run import load_result
    from tuners.storage import CONFIG_ATTR, load_study

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        res = load_result(study, storage)
    except KeyError as exc:
        raise ValueError(f"no study {study!r} in {storage}") from exc
    if res.selected is None:
        raise ValueError(f"study {study!r} has no selected solution (no feasible evaluation)")
    cfg = load_study(study, storage).user_attrs.get(CONFIG_ATTR) or {}
    names = cfg.get("param_names") or []
    fixed = ((cfg.get("problem") or {}).get("fixed_params")) or {}
    params = {str(k): float(v) for k, v in fixed.items()}
    params.update({n: float(res.selected[n]) for n in names})
    if not params:
        raise ValueError(f"study {study!r} stores no parameter names")
    return params


# --------------------------------------------------------------------- harness
def metric_columns(df: pd.DataFrame) -> list[str]:
    """Numeric result columns of a :func:`compare` table (not the identifiers)."""
    return [
        c
        for c in df.columns
        if c not in ID_COLUMNS and c != "episode" and pd.api.types.is_numeric_dtype(df[c])
    ]


def compare(
    env_ids: Iterable[str | EnvCase],
    drivers: Sequence[Driver],
    seeds: Iterable[int],
) -> pd.DataFrame:
    """Every driver on every env case and seed: one tidy row per episode.

    Columns: ``env`` (the case label), ``env_id``, ``driver``, ``seed``, ``scenario``,
    ``return``, ``env_steps`` and the episode metrics (units in their names; NaN
    where a driver's run does not report a metric).
    """
    cases = [_case(c) for c in env_ids]
    seeds = [int(s) for s in seeds]
    if not cases or not drivers or not seeds:
        raise ValueError("compare needs at least one env, one driver and one seed")
    names = [d.name for d in drivers]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"driver names must be unique; repeated: {dup}")
    labels = [c.label for c in cases]
    dup = sorted({n for n in labels if labels.count(n) > 1})
    if dup:
        raise ValueError(f"env case names must be unique; repeated: {dup} (set EnvCase.name)")
    frames = []
    for case in cases:
        for drv in drivers:
            part = drv.evaluate(case, seeds)
            part = part.drop(columns=["episode"], errors="ignore")
            part["env_id"] = part["env"]
            part["env"] = case.label
            part["driver"] = drv.name
            frames.append(part)
    df = pd.concat(frames, ignore_index=True)
    first = ["env", "env_id", "driver", "seed", "scenario", "return", "env_steps"]
    df = df[first + [c for c in df.columns if c not in first]]
    df["env_steps"] = df["env_steps"].astype(float)
    return df


def summary(df: pd.DataFrame, metrics: Sequence[str] | None = None) -> pd.DataFrame:
    """Mean and std over seeds per (env, driver); columns (metric, ``mean``|``std``)."""
    cols = list(metrics) if metrics is not None else [c for c in metric_columns(df) if c != "seed"]
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise ValueError(f"unknown metric(s) {missing}; available: {metric_columns(df)}")
    return df.groupby(["env", "driver"], sort=False)[cols].agg(["mean", "std"])


def format_summary(table: pd.DataFrame, digits: int = 4) -> pd.DataFrame:
    """A :func:`summary` table as ``"mean ± std"`` strings, one column per metric."""
    out = {}
    for metric in table.columns.get_level_values(0).unique():
        m, s = table[(metric, "mean")], table[(metric, "std")]
        cells = []
        for a, b in zip(m, s, strict=True):
            if not np.isfinite(a):
                cells.append("nan")
                continue
            # NaN std (one seed) and rounding noise of a constant count as 0
            b = 0.0 if np.isnan(b) or b <= 1e-9 * max(abs(a), 1e-12) else b
            cells.append(f"{a:.{digits}g} ± {b:.2g}")
        out[metric] = cells
    return pd.DataFrame(out, index=table.index)


def significance(
    df: pd.DataFrame,
    baseline: str,
    metrics: Sequence[str] | None = None,
    *,
    alternative: str = "two-sided",
) -> pd.DataFrame:
    """Paired Wilcoxon signed-rank tests of each driver against ``baseline``.

    Pairs are the same (env, seed). One row per (env, driver, metric): ``n_pairs``,
    the medians, ``median_diff`` (driver − baseline), the statistic and ``p_value``
    (NaN with a ``note`` where no test is meaningful: fewer than 2 pairs, every pair
    identical, or both drivers constant over the seeds — a scenario without
    randomness, whose seeds replicate one episode). With n pairs the smallest
    two-sided p is 2/2ⁿ (n = 5: 0.0625).
    """
    from scipy.stats import wilcoxon

    if alternative not in ("two-sided", "less", "greater"):
        raise ValueError(
            f"alternative must be 'two-sided', 'less' or 'greater'; got {alternative!r}"
        )
    drivers = list(dict.fromkeys(df["driver"]))
    if baseline not in drivers:
        raise ValueError(f"baseline driver {baseline!r} not in the table; drivers: {drivers}")
    cols = list(metrics) if metrics is not None else [c for c in metric_columns(df) if c != "seed"]
    rows = []
    for env, g in df.groupby("env", sort=False):
        base = g[g["driver"] == baseline].set_index("seed")
        for drv in drivers:
            if drv == baseline:
                continue
            other = g[g["driver"] == drv].set_index("seed")
            common = base.index.intersection(other.index)
            for col in cols:
                pair = pd.DataFrame({"b": base.loc[common, col], "d": other.loc[common, col]})
                pair = pair.astype(float).dropna()
                x, y = pair["d"].to_numpy(), pair["b"].to_numpy()
                row: dict[str, Any] = {
                    "env": env,
                    "driver": drv,
                    "baseline": baseline,
                    "metric": col,
                    "n_pairs": len(pair),
                    "baseline_median": float(np.median(y)) if len(y) else np.nan,
                    "driver_median": float(np.median(x)) if len(x) else np.nan,
                    "median_diff": float(np.median(x - y)) if len(x) else np.nan,
                    "statistic": np.nan,
                    "p_value": np.nan,
                    "note": "",
                }
                if len(pair) < 2:
                    row["note"] = "fewer than 2 paired seeds"
                elif np.all(x == y):
                    row["note"] = "identical on every seed"
                elif np.ptp(x) == 0 and np.ptp(y) == 0:
                    # deterministic scenario: the seeds are replicates of one episode
                    row["note"] = "no variation over seeds (deterministic episodes)"
                else:
                    res = wilcoxon(x, y, alternative=alternative)
                    row["statistic"] = float(res.statistic)
                    row["p_value"] = float(res.pvalue)
                rows.append(row)
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------ plots
def trajectory(case: str | EnvCase, driver: Driver, seed: int) -> pd.DataFrame:
    """The closed-loop DataFrame of one episode of ``driver`` (one row per control step)."""
    return driver.trajectory(_case(case), int(seed))[0]


def overlay_figure(case: str | EnvCase, drivers: Sequence[Driver], seed: int) -> Any:
    """Speed–distance overlay (and commands) of the drivers on one seed of one env case."""
    from train_envs.plotting import speed_distance_figure

    case = _case(case)
    runs: dict[str, pd.DataFrame] = {}
    scenario = None
    for d in drivers:
        df, scenario = d.trajectory(case, int(seed))
        runs[d.name] = df
    title = f"{case.label} — seed {seed}"
    if scenario is not None:
        title += f" ({scenario.name})"
    return speed_distance_figure(
        runs, title=title, s_stop_m=None if scenario is None else scenario.s_stop_m
    )
