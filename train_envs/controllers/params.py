"""The parameter space of a controller: its ordered tunable parameters and their scales.

:class:`ParamSpace` is the one place that maps a controller's tuning parameters
between their native values and the scaled variables the env and the tuners use:

* the env action, ``Box(-1, 1, (n,))``: component ``a_i ∈ [−1, 1]`` ↔ value by
  :meth:`TunableParam.from_unit` / :meth:`TunableParam.to_unit` (log-uniform where the
  spec says ``log``): with ``f = (a + 1)/2``, ``x = low + f (high − low)`` or
  ``x = exp(ln low + f (ln high − ln low))``, clipped to ``[low, high]``;
* the tuner's variables: ``space="unit"`` is the action scale above; ``space="native"``
  is ``x_i ∈ [low, high]``, or ``log10(value) ∈ [log10 low, log10 high]`` for a ``log``
  parameter (value ``10**x`` clipped to ``[low, high]``).

Validation (:meth:`ParamSpace.check`) names the parameter and its range in every error.
The arithmetic is :class:`TunableParam`'s, unchanged, so the env's action decode gives
the same values through this object as through the specs directly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from train_envs.controllers.base import TunableParam

SPACES = ("unit", "native")

__all__ = ["SPACES", "ParamSpace"]


@dataclass(frozen=True)
class ParamSpace:
    """Ordered tunable parameters (``specs``) with their encodings."""

    specs: tuple[TunableParam, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "specs", tuple(self.specs))
        names = [p.name for p in self.specs]
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names must be distinct, got {names}")

    @classmethod
    def of(cls, specs: Iterable[TunableParam], names: Sequence[str] | None = None) -> ParamSpace:
        """The space of ``specs`` (a controller's ``tunable_params()``), or of the subset
        ``names`` in that order; an unknown name is an error listing the allowed ones."""
        by_name = {p.name: p for p in specs}
        if names is None:
            return cls(tuple(by_name.values()))
        unknown = [n for n in names if n not in by_name]
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; allowed: {list(by_name)}")
        return cls(tuple(by_name[n] for n in names))

    # ---------------------------------------------------------------- names
    @property
    def names(self) -> list[str]:
        return [p.name for p in self.specs]

    def __len__(self) -> int:
        return len(self.specs)

    def __iter__(self):  # noqa: ANN204 - iterator of TunableParam
        return iter(self.specs)

    def __getitem__(self, name: str) -> TunableParam:
        for p in self.specs:
            if p.name == name:
                return p
        raise KeyError(f"no parameter {name!r}; allowed: {self.names}")

    # ----------------------------------------------------------- validation
    def check(self, params: Mapping[str, float]) -> dict[str, float]:
        """``params`` validated (names known, values finite and within range), as floats."""
        unknown = set(params) - set(self.names)
        if unknown:
            raise ValueError(
                f"params {sorted(unknown)} are not tunable here; allowed: {self.names}"
            )
        return {p.name: p.check(params[p.name]) for p in self.specs if p.name in params}

    def complete(
        self, params: Mapping[str, float], defaults: Mapping[str, float]
    ) -> dict[str, float]:
        """Every parameter of the space: ``params`` validated, the others from ``defaults``."""
        given = self.check(params)
        return {p.name: given[p.name] if p.name in given else defaults[p.name] for p in self.specs}

    # ------------------------------------------------------------ env action
    def encode_action(
        self, params: Mapping[str, float], defaults: Mapping[str, float]
    ) -> np.ndarray:
        """The absolute-mode action (float64, ``to_unit`` of each value) that sets
        ``params``; parameters it omits take ``defaults``."""
        values = self.complete(params, defaults)
        return np.array([p.to_unit(values[p.name]) for p in self.specs], dtype=np.float64)

    def decode_action(
        self,
        unit: Sequence[float],
        base_unit: Sequence[float] | None = None,
        base_params: Mapping[str, float] | None = None,
    ) -> dict[str, float]:
        """Parameter values of the unit components ``unit`` (``from_unit`` of each).

        A component equal to its ``base_unit`` entry decodes to the ``base_params``
        value exactly (``from_unit`` and ``to_unit`` are inverse only to rounding).
        """
        if len(unit) != len(self.specs):
            raise ValueError(f"need {len(self.specs)} components ({self.names}), got {len(unit)}")
        if base_unit is None or base_params is None:
            return {p.name: p.from_unit(u) for p, u in zip(self.specs, unit, strict=True)}
        return {
            p.name: base_params[p.name] if u == base_unit[i] else p.from_unit(u)
            for i, (p, u) in enumerate(zip(self.specs, unit, strict=True))
        }

    def unit_of(self, params: Mapping[str, float]) -> list[float]:
        """``to_unit`` of every parameter of the space (all must be given)."""
        return [p.to_unit(params[p.name]) for p in self.specs]

    # -------------------------------------------------------- tuner variables
    def bounds(self, space: str = "unit") -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the tuner's variables in ``space``."""
        _check_space(space)
        n = len(self.specs)
        if space == "unit":
            return -np.ones(n), np.ones(n)
        xl = np.array([math.log10(p.low) if p.log else p.low for p in self.specs])
        xu = np.array([math.log10(p.high) if p.log else p.high for p in self.specs])
        return xl, xu

    def from_x(self, x: Sequence[float], space: str = "unit") -> dict[str, float]:
        """Parameter values of the tuner's point ``x`` in ``space``."""
        _check_space(space)
        out = {}
        for p, v in zip(self.specs, np.asarray(x, float), strict=True):
            if space == "unit":
                out[p.name] = p.from_unit(float(v))
            else:
                val = 10.0 ** float(v) if p.log else float(v)
                out[p.name] = min(p.high, max(p.low, val))
        return out

    def to_x(
        self,
        params: Mapping[str, float],
        space: str = "unit",
        defaults: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        """The tuner's point of ``params`` (missing names from ``defaults``), clipped to
        :meth:`bounds`."""
        _check_space(space)
        x = []
        for p in self.specs:
            v = float(params[p.name] if p.name in params or defaults is None else defaults[p.name])
            if space == "unit":
                x.append(p.to_unit(v))
            else:
                x.append(math.log10(v) if p.log else v)
        xl, xu = self.bounds(space)
        return np.clip(np.array(x), xl, xu)


def _check_space(space: str) -> None:
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")
