"""Reproductions of the papers' tables: our closed-loop numbers beside the published ones.

One module per paper (``paper000.py`` ...); each exposes ``reproduce_paperNNN(seed=0)
-> pandas.DataFrame``, which the CLI's ``train-envs reproduce <paper>`` runs. Modules
are imported lazily so that a reproduction's dependencies (cvxpy for 003, say) load only
when it runs. A reproduction that needs a layer above train_envs (paper 004 tunes with
:mod:`tuners`) is registered as an entry point of the group ``train_envs.reproduce``
(see :mod:`train_envs.cli_args`) by the package that holds it. The write-ups, with the
figures we measured, are in ``docs/papers/paperNNN.md``.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable

import pandas as pd

from train_envs.cli_args import REPRODUCE_GROUP, registered

#: paper key -> "module:function" under this package
_ENTRIES: dict[str, str] = {
    "paper000": "paper000:reproduce_paper000",
    "paper001": "paper001:reproduce_paper001",
    "paper002": "paper002:reproduce_paper002",
    "paper003": "paper003:reproduce_paper003",
}


def _present() -> list[str]:
    """Papers of this package whose module is present."""
    out = []
    for key, entry in _ENTRIES.items():
        mod = entry.split(":")[0]
        if importlib.util.find_spec(f"{__name__}.{mod}") is not None:
            out.append(key)
    return out


def list_reproductions() -> list[str]:
    """Papers with a reproduction: this package's and the registered ones, in name order."""
    return sorted({*_present(), *registered(REPRODUCE_GROUP)})


def get_reproduction(paper: str) -> Callable[..., pd.DataFrame]:
    """The reproduction function of ``paper`` (e.g. ``"paper000"``)."""
    if paper in _ENTRIES:
        mod, fn = _ENTRIES[paper].split(":")
        return getattr(importlib.import_module(f"{__name__}.{mod}"), fn)
    plugins = registered(REPRODUCE_GROUP)
    if paper in plugins:
        return plugins[paper].load()
    choices = sorted({*_ENTRIES, *plugins})
    raise ValueError(f"no reproduction for {paper!r}; choose one of: {', '.join(choices)}")


def reproduce_paper000(seed: int = 0) -> pd.DataFrame:
    """Paper 000's Tables 2 and 4 (see :mod:`train_envs.reproduce.paper000`)."""
    return get_reproduction("paper000")(seed=seed)
