"""The benchmark disturbance: what each disturbance seed draws, on top of every scenario.

The named scenarios are deterministic apart from their own disturbances, so without a
benchmark disturbance every seed would repeat the same episode. A benchmark
disturbance is a set of :class:`~train_envs.scenarios.DisturbanceSpec` fields applied
over a scenario's own disturbance, field by field (paper 000's wind scenarios keep
their wind; a field named in both takes the benchmark's value). Presets
(:data:`DISTURBANCES`):

* ``load`` (default): the load variation and resistance disturbance of paper 004's
  evaluation and the README's demo, mass × U(0.9, 1.15) at reset and a
  piecewise-constant uniform resistance disturbance of ±0.03 m/s² (1 s hold);
* ``none``: each scenario as it is named (the undisturbed runs).

Or any JSON object of ``DisturbanceSpec`` fields, e.g.
``{"mass_factor_range": [0.95, 1.05]}``; it is checked through ``DisturbanceSpec``
(one-line ``ValueError`` naming the field). Its canonical JSON (sorted fields, ranges
as lists) is recorded in the tidy table and the leaderboard and is part of a cell's
resume key.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import fields, replace
from typing import Any

from train_envs.scenarios import DisturbanceSpec, Scenario

__all__ = [
    "DEFAULT_DISTURBANCE",
    "DISTURBANCES",
    "apply_disturbance",
    "disturbance_label",
    "resolve_disturbance",
]

#: preset name -> the DisturbanceSpec fields it sets over a scenario's own
DISTURBANCES: dict[str, dict[str, Any]] = {
    "load": {"mass_factor_range": [0.9, 1.15], "random_bound_mps2": 0.03},
    "none": {},
}
DEFAULT_DISTURBANCE = "load"
_FIELDS = tuple(f.name for f in fields(DisturbanceSpec))


def _spec(base: DisturbanceSpec, over: Mapping[str, Any]) -> DisturbanceSpec:
    kw = {k: tuple(v) if isinstance(v, list) else v for k, v in over.items()}
    return replace(base, **kw)


def resolve_disturbance(spec: str | Mapping[str, Any] | None) -> str:
    """The canonical JSON of a benchmark disturbance: a preset name, a JSON object text
    or a mapping of ``DisturbanceSpec`` fields (``None``: the default preset)."""
    if spec is None:
        spec = DEFAULT_DISTURBANCE
    if isinstance(spec, str):
        if spec.lstrip().startswith("{"):
            try:
                spec = json.loads(spec)
            except json.JSONDecodeError as exc:
                raise ValueError(f"disturbance: not a JSON object ({exc.msg})") from None
        elif spec in DISTURBANCES:
            spec = DISTURBANCES[spec]
        else:
            raise ValueError(
                f"disturbance must be a preset ({', '.join(DISTURBANCES)}) or a JSON object "
                f"of DisturbanceSpec fields, got {spec!r}"
            )
    if not isinstance(spec, Mapping):
        raise ValueError(f"disturbance must be a JSON object, got {spec!r}")
    unknown = sorted(set(spec) - set(_FIELDS))
    if unknown:
        raise ValueError(
            f"disturbance: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(_FIELDS)}"
        )
    try:
        _spec(DisturbanceSpec(), spec)
    except TypeError as exc:
        raise ValueError(f"disturbance: {exc}") from None
    canon = {k: list(v) if isinstance(v, (tuple, list)) else v for k, v in spec.items()}
    return json.dumps(canon, sort_keys=True)


def disturbance_label(text: str) -> str:
    """The preset name of a canonical disturbance JSON, or the JSON itself."""
    for name, fields_ in DISTURBANCES.items():
        if json.dumps(fields_, sort_keys=True) == text:
            return name
    return text


def apply_disturbance(sc: Scenario, text: str) -> Scenario:
    """``sc`` with the disturbance fields of ``text`` (canonical JSON) over its own."""
    over = json.loads(text)
    return sc if not over else replace(sc, disturbance=_spec(sc.disturbance, over))
