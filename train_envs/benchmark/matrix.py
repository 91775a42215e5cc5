"""The benchmark's matrix: which scenarios, which controllers, and which pairs run.

A benchmark scenario is a named scenario (``train-envs list scenarios``) or a station
pair of a real line, ``<line>_<i>_<j>`` (stop ``i`` to stop ``j`` of the line of the
named real-line scenario ``<line>``, e.g. ``yizhuang_3_4``; built by
:func:`train_envs.scenarios.real_line_scenario` with that scenario's track and train).
Scenario sets stand for several at once (:data:`SCENARIO_SETS`):

* ``all``: every named scenario, in the catalogue's order;
* ``real-lines``: every consecutive station pair of the Yizhuang and Zürich lines.

A pair (scenario, controller) is supported when the controller accepts the scenario
at construction (:func:`train_envs.controllers.requirements.unsupported_reason`);
an unsupported pair is a row of the leaderboard with its reason, not a run.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from functools import cache

from train_envs.benchmark.disturbance import apply_disturbance
from train_envs.controllers import list_controllers
from train_envs.controllers.requirements import unsupported_reason
from train_envs.lines import get_track
from train_envs.scenarios import Scenario, get_scenario, list_scenarios, real_line_scenario
from train_envs.validation import check_choice

__all__ = [
    "REAL_LINES",
    "SCENARIO_SETS",
    "benchmark_scenario",
    "pair_reasons",
    "real_line_pairs",
    "resolve_controllers",
    "resolve_scenarios",
]

#: the named real-line scenarios whose lines the ``real-lines`` set covers stop by stop
REAL_LINES: tuple[str, ...] = ("yizhuang", "zurich")
_PAIR = re.compile(r"^(?P<line>.+)_(?P<i>\d+)_(?P<j>\d+)$")


def real_line_pairs(lines: Sequence[str] = REAL_LINES) -> list[str]:
    """The names ``<line>_<i>_<i+1>`` of every consecutive station pair of ``lines``."""
    out = []
    for line in lines:
        sc = get_scenario(line)
        n_stops = len(get_track(sc.extra["line"]).stops_m)
        out.extend(f"{line}_{i}_{i + 1}" for i in range(n_stops - 1))
    return out


#: name -> the scenario names it stands for (computed when asked)
SCENARIO_SETS: dict[str, Callable[[], list[str]]] = {
    "all": list_scenarios,
    "real-lines": real_line_pairs,
}


@cache
def benchmark_scenario(name: str) -> Scenario:
    """The scenario of a benchmark name: a named scenario or a real-line station pair."""
    if name in list_scenarios():
        return get_scenario(name)
    m = _PAIR.match(name)
    if m is None or m["line"] not in REAL_LINES:
        raise ValueError(
            f"unknown scenario {name!r}; choose a named scenario ({', '.join(list_scenarios())}), "
            f"a set ({', '.join(SCENARIO_SETS)}) or a station pair <line>_<i>_<j> of "
            f"{', '.join(REAL_LINES)}"
        )
    base = get_scenario(m["line"])
    return real_line_scenario(
        base.extra["line"], base.train.name, int(m["i"]), int(m["j"]), name=name
    )


def resolve_scenarios(names: Sequence[str] | None) -> list[str]:
    """Scenario names with the sets expanded, duplicates dropped, order kept (default:
    ``all``). Every name is checked (``ValueError`` naming it)."""
    out: list[str] = []
    for name in names or ["all"]:
        expanded = SCENARIO_SETS[name]() if name in SCENARIO_SETS else [name]
        for n in expanded:
            benchmark_scenario(n)
            if n not in out:
                out.append(n)
    return out


def resolve_controllers(names: Sequence[str] | None) -> list[str]:
    """Controller names (default: every controller), checked, duplicates dropped."""
    out: list[str] = []
    for name in names or list_controllers():
        check_choice("controller", name, list_controllers())
        if name not in out:
            out.append(name)
    return out


def pair_reasons(
    scenarios: Sequence[str], controllers: Sequence[str], disturbance: str = "{}"
) -> dict[tuple[str, str], str]:
    """``(scenario, controller) -> reason`` of every unsupported pair, the scenarios
    under the benchmark ``disturbance`` (canonical JSON)."""
    out = {}
    for sc in scenarios:
        scenario = apply_disturbance(benchmark_scenario(sc), disturbance)
        for c in controllers:
            reason = unsupported_reason(c, scenario)
            if reason is not None:
                out[sc, c] = reason
    return out
