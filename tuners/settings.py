"""The settings of a tuning run: defaults, and what a resume may and may not change.

A setting left out (``None``) takes its default in a new study and its stored value on
resume. Every setting below decides what is computed or selected — the problem
(env, seeds, objectives, constraints, config, parameters, space), the algorithm's
construction and random stream (algo, pop, seed, algo kwargs, the initial defaults)
and the weights and scales that steer the decomposition algorithms *and* pick the
selected solution (target weights, f bounds, normalisation): on resume each one given
with another value than the stored one is refused, naming it and both values. So a
study has one selected solution, the same in the report, ``tune show``, the returned
result, the CSV, the plots and the hold-out table. ``iters`` is the one exception:
a resume may extend (or shorten) the run; the stored value is updated.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

__all__ = ["DEFAULTS", "FIXED_ON_RESUME", "resolve_settings"]

#: defaults of a new study
DEFAULTS: dict[str, Any] = {
    "algo": "mowoa",
    "pop": 40,
    "iters": 100,
    "seed": 1,
    "seeds": [0],
    "objectives": None,  # the problem's: 004's five the scenario reports
    "constraints": None,  # the problem's: max_overspeed_mps <= 0
    "config": {},
    "params": None,  # all exposed
    "space": "unit",
    "target_weights": None,  # equal
    "f_bounds": None,
    "normalization": "auto",
    "include_defaults": True,
    "algo_kwargs": {},
}
#: settings a resume must not change
FIXED_ON_RESUME = tuple(k for k in DEFAULTS if k != "iters")


def _norm(value: Any) -> Any:
    """A JSON-plain form for comparing a given setting with its stored value."""
    return json.loads(json.dumps(value, sort_keys=True, default=lambda o: list(o)))


def stored_settings(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """The settings of a stored ``tuner_config`` in :data:`DEFAULTS`' terms."""
    fp = cfg.get("problem") or {}
    env = fp.get("kind") == "env"
    return {
        "algo": cfg.get("algo"),
        "pop": cfg.get("pop"),
        "iters": cfg.get("iters"),
        "seed": cfg.get("seed"),
        "seeds": cfg.get("seeds") or None,
        "objectives": list(fp["objectives"]) if env else None,
        "constraints": {str(k): float(v) for k, v in fp["constraints"]} if env else None,
        "config": fp.get("config", {}) if env else {},
        "params": [p[0] for p in fp["params"]] if env else None,
        "space": fp.get("space", "unit") if env else "unit",
        "target_weights": cfg.get("target_weights"),
        "f_bounds": cfg.get("f_bounds"),
        "normalization": cfg.get("normalization", "auto"),
        "include_defaults": cfg.get("include_defaults", True),
        "algo_kwargs": cfg.get("algo_kwargs") or {},
    }


def _comparable(key: str, value: Any) -> Any:
    if value is None:
        return None
    if key == "objectives":
        from tuners.problem import objective_column

        return [objective_column(str(o)) for o in value]
    if key == "constraints":
        return {str(k): float(v) for k, v in dict(value).items()}
    if key in ("seeds", "params"):
        return [int(v) for v in value] if key == "seeds" else [str(v) for v in value]
    if key == "target_weights":
        return [float(v) for v in value]
    if key == "f_bounds":
        return [[float(v) for v in b] for b in value]
    return _norm(value)


def resolve_settings(
    given: Mapping[str, Any], stored_cfg: Mapping[str, Any] | None, study_name: str
) -> dict[str, Any]:
    """The run's settings: ``given`` (``None`` = left out) over the stored ones on resume
    (``stored_cfg`` = the study's ``tuner_config``) or over :data:`DEFAULTS`.

    Raises ``ValueError`` naming every fixed setting that differs from the stored one.
    """
    unknown = sorted(set(given) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown settings {unknown}; known: {sorted(DEFAULTS)}")
    if stored_cfg is None:
        out = dict(DEFAULTS)
        out.update({k: v for k, v in given.items() if v is not None})
        return out
    stored = stored_settings(stored_cfg)
    diffs = []
    for key in FIXED_ON_RESUME:
        val = given.get(key)
        if val is None:
            continue
        a, b = _comparable(key, stored.get(key)), _comparable(key, val)
        if key in ("config", "algo_kwargs") and a is None:
            a = {}
        if a != b:
            diffs.append(f"{key} (stored {stored.get(key)!r}, given {val!r})")
    if diffs:
        raise ValueError(
            f"cannot resume study {study_name!r}: {'; '.join(diffs)} — leave "
            f"{'it' if len(diffs) == 1 else 'them'} out to use the stored value, or start "
            "another study"
        )
    out = {k: (given.get(k) if given.get(k) is not None else stored.get(k)) for k in DEFAULTS}
    for key in ("algo", "pop", "iters", "seed", "seeds", "space", "normalization"):
        if out[key] is None:
            out[key] = DEFAULTS[key]
    return out
