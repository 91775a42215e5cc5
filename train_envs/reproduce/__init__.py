"""Reproductions of the papers' tables: our closed-loop numbers beside the published ones.

One module per paper (``paper000.py`` ...); each exposes ``reproduce_paperNNN(seed=0)
-> pandas.DataFrame``, which the CLI's ``train-envs reproduce <paper>`` runs, and
``figures_paperNNN(table, runs) -> {name: Figure}``: with ``--out DIR`` the CLI passes
a ``runs`` dict that the reproduction fills with its runs' DataFrames (where it takes
one) and writes the table as CSV and every figure as PNG (:func:`write_reproduction`). Modules
are imported lazily so that a reproduction's dependencies (cvxpy for 003, say) load only
when it runs. A reproduction that needs a layer above train_envs (paper 004 tunes with
:mod:`tuners`) is registered as an entry point of the group ``train_envs.reproduce``
(see :mod:`train_envs.cli_args`) by the package that holds it. The write-ups, with the
figures we measured, are in ``docs/papers/paperNNN.md``.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

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


def get_figures(paper: str) -> Callable[..., dict[str, Any]] | None:
    """``figures_<paper>`` of the module that holds the reproduction (None if it has none)."""
    fn = get_reproduction(paper)
    return getattr(importlib.import_module(fn.__module__), f"figures_{paper}", None)


def write_reproduction(
    paper: str, out: str | Path, seed: int = 0
) -> tuple[pd.DataFrame, list[Path]]:
    """Run ``paper``'s reproduction; write ``<out>/<paper>.csv`` and its figures
    ``<out>/<paper>_<name>.png``. Returns the table and the files written."""
    fn = get_reproduction(paper)
    runs: dict[Any, pd.DataFrame] = {}
    kwargs: dict[str, Any] = {"seed": seed}
    if "runs" in inspect.signature(fn).parameters:
        kwargs["runs"] = runs
    table = fn(**kwargs)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / f"{paper}.csv"]
    table.to_csv(files[0], index=False)
    figures = get_figures(paper)
    for name, fig in (figures(table, runs) if figures is not None else {}).items():
        files.append(out / f"{paper}_{name}.png")
        fig.savefig(files[-1], dpi=110)
    return table, files


def reproduce_paper000(seed: int = 0) -> pd.DataFrame:
    """Paper 000's Tables 2 and 4 (see :mod:`train_envs.reproduce.paper000`)."""
    return get_reproduction("paper000")(seed=seed)
