"""Per-env contract pages, generated from the code: ``docs/envs/<Id>.md``.

``python -m train_envs.envs.contract [--out docs/envs] [--check]`` builds every
registered id and writes one Markdown page per id: the scenario and the inner
controller, the action parameters (ranges, scale, the paper's defaults and the action
that sets them), the observation features (definitions from
:mod:`train_envs.envs.observation`, with this env's scales), the reward terms with the
id's weights (definitions from :mod:`train_envs.envs.reward`), the safety cost, and
termination and truncation. ``--check`` writes nothing and exits 1 if a committed page
differs from the generated one (``tests/envs/test_contract_pages.py`` runs it).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from train_envs.envs import observation as _observation
from train_envs.envs import reward as _reward
from train_envs.envs.evaluation import params_to_action
from train_envs.envs.registration import ENV_SPECS, register_envs

__all__ = ["contract_page", "feature_definitions", "main", "page_name", "write_pages"]

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "docs" / "envs"


def _num(x: float) -> str:
    """A number for a table: 4 significant digits, no ``e-11`` noise for zero."""
    x = float(x)
    if x == 0.0:
        return "0"
    if not math.isfinite(x):
        return "∞" if x > 0 else ("−∞" if x < 0 else "NaN")
    return f"{x:.4g}".replace("-", "−")


def page_name(env_id: str) -> str:
    """``TrainEnvs/Urban004-v0`` → ``Urban004-v0.md``."""
    return env_id.split("/")[-1] + ".md"


def feature_definitions() -> dict[str, str]:
    """Feature name (``grad_ahead_i`` for the indexed ones) → its definition, read from
    the table of :mod:`train_envs.envs.observation`'s docstring."""
    doc = _observation.__doc__ or ""
    out: dict[str, str] = {}
    last = None
    for line in doc.splitlines():
        m = re.match(r"^``([\w<>]+)``\s+(.*)$", line)
        if m:
            last = m.group(1)
            out[last] = m.group(2).strip()
        elif last and line.startswith(" " * 10) and line.strip():
            out[last] += " " + line.strip()
        elif line.startswith("="):
            last = None
    return out


def _term_definitions() -> dict[str, str]:
    """Objective / cost component → its formula, from :mod:`train_envs.envs.reward`."""
    doc = _reward.__doc__ or ""
    out: dict[str, str] = {}
    last = None
    names = set(_reward.OBJECTIVES) | set(_reward.COST_COMPONENTS)
    for line in doc.splitlines():
        m = re.match(r"^    (\w+)\s+= (.*)$", line)
        if m and m.group(1) in names:
            last = m.group(1)
            out[last] = m.group(2).strip()
        elif last and re.match(r"^\s{10,}\S", line):
            out[last] += " " + line.strip()
        else:
            last = None
    return out


def _feature_key(name: str) -> str:
    m = re.match(r"^(grad_ahead|limit_ahead)_\d+$", name)
    if m:
        return f"{m.group(1)}_i"
    if name.startswith("prev_action_"):
        return "prev_action_<param>"
    return name


def _row(cells: Sequence[Any]) -> str:
    return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"


def contract_page(env_id: str) -> str:
    """The Markdown contract page of a registered id (deterministic: no timings)."""
    import gymnasium as gym

    env = gym.make(env_id)
    try:
        return _page(env_id, env)
    finally:
        env.close()


def _page(env_id: str, env: Any) -> str:
    base = env.unwrapped
    cfg, blurb = ENV_SPECS[env_id]
    st = base.settings
    env.reset(seed=0)
    sc = base.scenario
    obs = base.observation_type
    act = base.action_type
    L: list[str] = [f"# `{env_id}`", "", f"{blurb[0].upper()}{blurb[1:]}.", ""]
    L += [
        "Generated from the code by `python -m train_envs.envs.contract` (a test checks "
        "that this page matches it). Values marked *at reset(seed=0)* are those of the "
        "episode that seed draws.",
        "",
        "```python",
        "import gymnasium as gym",
        "import train_envs  # registers the ids",
        "",
        f'env = gym.make("{env_id}")  # config={{...}} merges over the id\'s own',
        "```",
        "",
        "The id's own config (merged over `TrainTuningEnv.default_config()`):",
        "",
        "```python",
        repr(cfg),
        "```",
        "",
        "## Scenario and controller",
        "",
        "| item | value |",
        "|---|---|",
    ]
    rl = st.scenario.real_line
    if rl is not None:
        L.append(
            _row(
                [
                    "scenario",
                    f"real line: track `{rl['track']}`, train `{rl['train']}`; each reset "
                    "draws a station-to-station run",
                ]
            )
        )
        L.append(_row(["run at reset(seed=0)", f"`{sc.name}`"]))
    else:
        L.append(_row(["scenario", f"`{st.scenario.name}`: {sc.description}"]))
    L += [
        _row(["train", f"{sc.train.name}, {sc.n_cars} car(s), input mode `{sc.input_mode}`"]),
        _row(["controller", f"`{st.controller.name}` ({type(base.controller).__name__})"]),
        _row(
            [
                "fixed controller arguments",
                f"`{st.controller.params}`" if st.controller.params else "none",
            ]
        ),
        _row(["control period dt_ctrl", f"{_num(sc.dt_ctrl_s)} s"]),
        _row(["plant step dt_sim", f"{_num(sc.dt_sim_s)} s"]),
        _row(
            [
                "env step",
                f"{st.episode.decision_interval} control steps = "
                f"{_num(st.episode.decision_interval * sc.dt_ctrl_s)} s",
            ]
        ),
        _row(["stop s_stop", "none (cruise)" if sc.s_stop_m is None else f"{_num(sc.s_stop_m)} m"]),
        _row(
            [
                "scheduled time",
                "none" if sc.scheduled_time_s is None else f"{_num(sc.scheduled_time_s)} s",
            ]
        ),
        _row(["t_max", f"{_num(sc.t_max_s)} s"]),
        _row(["disturbance at reset(seed=0)", f"`{_disturbance_text(sc.disturbance)}`"]),
        "",
    ]
    # ------------------------------------------------------------------ action
    specs = act.specs
    default_action = params_to_action(env, base.default_params())
    L += [
        "## Action",
        "",
        f"`Box(-1, 1, ({len(specs)},), float32)`, mode `{st.action.mode}`"
        + (f" (delta_scale {_num(st.action.delta_scale)})" if st.action.mode == "delta" else "")
        + ". Component i maps −1 → low, +1 → high, linearly (log-linearly where the scale "
        "is log); the zero action is the middle of each range, **not** the paper's "
        "default. The last column is the action component that sets the default.",
        "",
        "| i | parameter | meaning | low | high | scale | default | action for the default |",
        "|---:|---|---|---:|---:|---|---:|---:|",
    ]
    defaults = base.default_params()
    for i, p in enumerate(specs):
        L.append(
            _row(
                [
                    i,
                    f"`{p.name}`",
                    p.description or "",
                    _num(p.low),
                    _num(p.high),
                    "log" if p.log else "linear",
                    _num(defaults[p.name]),
                    f"{float(default_action[i]):+.6f}",
                ]
            )
        )
    if st.action.bounds:
        L += [
            "",
            "The id narrows the controller's range of "
            + ", ".join(f"`{n}`" for n in st.action.bounds)
            + " (`action_bounds`; the table shows the narrowed range).",
        ]
    timing = base.controller.PARAMS_TAKE_EFFECT
    if timing:
        L += ["", "When a new action takes effect: " + timing]
    fixed = {k: v for k, v in defaults.items() if k not in {p.name for p in specs}}
    L += [
        "",
        "Start from the paper's defaults (a constant action that reproduces the "
        "controller with its default parameters):",
        "",
        "```python",
        "from train_envs.envs import params_to_action",
        "",
        "a0 = params_to_action(env, env.unwrapped.default_params())",
        "```",
        "",
    ]
    if fixed:
        L += [f"Parameters not in the action keep their values: `{_rounded(fixed)}`.", ""]
    # -------------------------------------------------------------- observation
    defs = feature_definitions()
    scales = {
        "v": f"v_max = {_num(obs._v_scale)} m/s",
        "u": f"max traction force = {_num(obs._u_scale)} N",
        "du": f"{_num(obs._du_scale)} N",
        "limit_ahead_i": f"v_max = {_num(obs._v_scale)} m/s",
        "dist_to_stop": "s_end = "
        + (f"{_num(obs._end)} m" + ("" if sc.s_stop_m is not None else " (profile end)")),
    }
    n_prev = len(obs._preview)
    L += [
        "## Observation",
        "",
        f"`Box({-_observation.OBS_CLIP:g}, {_observation.OBS_CLIP:g}, ({len(obs.names)},), "
        "float32)`: every feature is dimensionless (divided by the scale in its "
        f"definition), NaN → 0, clipped to ±{_observation.OBS_CLIP:g}. Preview: "
        f"{n_prev} point(s) over {_num(st.observation.preview_m)} m.",
        "",
        "| i | feature | definition | this env's scale (at reset(seed=0)) |",
        "|---:|---|---|---|",
    ]
    for i, name in enumerate(obs.names):
        key = _feature_key(name)
        scale = scales.get(key, "")
        if key in ("grad_ahead_i", "limit_ahead_i"):
            at = f"at s + {_num(obs._preview[int(name.rsplit('_', 1)[1])])} m"
            scale = f"{at}; {scale}" if scale else at
        L.append(_row([i, f"`{name}`", defs.get(key, ""), scale]))
    # ------------------------------------------------------------------- reward
    terms = _term_definitions()
    w = base.reward_type.weights
    L += [
        "",
        "## Reward",
        "",
        '`reward = −Σ_i w_i c_i` per env step; `info["objectives"]` holds every c_i. '
        "Sums run over the control steps k of the env step (period dt = dt_ctrl); "
        "`stop` and `punctuality` count on the last env step only.",
        "",
        "| objective c_i | definition | weight w_i |",
        "|---|---|---:|",
    ]
    for name in _reward.OBJECTIVES:
        L.append(_row([f"`{name}`", f"`{terms.get(name, '')}`", _num(w[name])]))
    L += [
        "",
        'Safety cost `info["cost"]` (≥ 0, 0 on a safe step; Safety-Gymnasium\'s '
        'convention) = the sum of `info["cost_components"]`; they are also part of '
        "`violation`:",
        "",
        "| component | definition |",
        "|---|---|",
    ]
    for name in _reward.COST_COMPONENTS:
        L.append(_row([f"`{name}`", f"`{terms.get(name, '')}`"]))
    sup = st.episode.supervisor()
    L += [
        "",
        f"ATP: {'on' if sup.atp else 'off'}"
        + (f", brakes above the limit + {_num(sup.margin_mps * 3.6)} km/h" if sup.atp else "")
        + (
            f"; stopping window {_num(sc.stop_window())} m beyond the stop."
            if sc.s_stop_m is not None
            else "."
        ),
        "",
    ]
    # -------------------------------------------------------------- episode end
    if sc.s_stop_m is not None:
        term = (
            "the train has stopped after moving (held at standstill after v > 0.1 m/s), or "
            f"its head is more than {_num(sc.overrun_m)} m beyond the stop"
        )
    else:
        term = f"t ≥ t_max = {_num(sc.t_max_s)} s (a cruise ends on time)"
    trunc = "the runner's step budget"
    if sc.s_stop_m is not None:
        trunc = f"t ≥ t_max = {_num(sc.t_max_s)} s or {trunc}"
    if st.episode.max_steps is not None:
        trunc += f", or {st.episode.max_steps} env steps"
    L += [
        "## Episode end",
        "",
        f"- **terminated**: {term}"
        + (
            "; or the first safety violation (`supervision.end_on_violation`)"
            if sup.end_on_violation
            else ""
        )
        + ".",
        f"- **truncated**: {trunc} (when not terminated).",
        "- `step()` before `reset()` or after the end raises `gymnasium.error.ResetNeeded`.",
        "",
    ]
    return "\n".join(L)


def _disturbance_text(d: Any) -> str:
    import dataclasses

    base = type(d)()
    diff = {
        f.name: getattr(d, f.name)
        for f in dataclasses.fields(d)
        if getattr(d, f.name) != getattr(base, f.name)
    }
    return repr(diff) if diff else "none"


def _rounded(params: dict[str, Any]) -> dict[str, Any]:
    return {
        k: float(_num(v).replace("−", "-")) if isinstance(v, float) else v
        for k, v in params.items()
    }


def index_page(env_ids: Sequence[str]) -> str:
    """``docs/envs/README.md``: one line per id with its page."""
    L = [
        "# Env contract pages",
        "",
        "One page per registered id, generated from the code by "
        "`python -m train_envs.envs.contract`: observation features, action parameters "
        "with ranges and defaults, reward terms, termination.",
        "",
        "| id | page | what |",
        "|---|---|---|",
    ]
    for env_id in env_ids:
        L.append(
            _row(
                [f"`{env_id}`", f"[{page_name(env_id)}]({page_name(env_id)})", ENV_SPECS[env_id][1]]
            )
        )
    return "\n".join(L) + "\n"


def generated_pages() -> dict[str, str]:
    """File name → content of every page (the index ``README.md`` included)."""
    ids = register_envs()
    pages = {page_name(i): contract_page(i) for i in ids}
    pages["README.md"] = index_page(ids)
    return pages


def write_pages(out: Path = DEFAULT_OUT, check: bool = False) -> list[str]:
    """Write (or with ``check`` only compare) the pages; returns the files that differ."""
    out = Path(out)
    differ = []
    for name, text in generated_pages().items():
        path = out / name
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            differ.append(name)
            if not check:
                out.mkdir(parents=True, exist_ok=True)
                path.write_text(text, encoding="utf-8")
    return differ


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m train_envs.envs.contract", description=__doc__)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="folder (default docs/envs)")
    p.add_argument("--check", action="store_true", help="compare only; exit 1 on a difference")
    args = p.parse_args(argv)
    differ = write_pages(args.out, check=args.check)
    if args.check and differ:
        print(f"stale env pages in {args.out}: {', '.join(differ)}", file=sys.stderr)
        return 1
    print(("differ: " if args.check else "written: ") + (", ".join(differ) or "none"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
