"""The final pick of a tuning run: Pareto set, normalisation and 004's cosine selection.

:func:`summarize` marks the Pareto set and the selected solution in an evaluations
frame; :func:`run_weight_vectors` gives the run's subproblem weight vectors (the target
among them). Both are re-exported by :mod:`tuners.run`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from tuners.mowoa import nondominated, select_by_cosine, tchebycheff, weight_vectors

__all__ = ["DEFAULTS_SCALE_FLOOR", "NORMALIZATIONS", "run_weight_vectors", "summarize"]


def run_weight_vectors(n_obj: int, n: int, target: Sequence[float] | None = None) -> np.ndarray:
    """The run's subproblem weight vectors: :func:`tuners.mowoa.weight_vectors` with the
    one closest in angle to ``target`` replaced by the (normalised) target itself, so
    that the user's preference is one of the subproblems and 004's cosine pick selects
    exactly its elite."""
    W = weight_vectors(n_obj, n).copy()
    if target is None or n_obj == 1:
        return W
    w = np.asarray(target, float)
    w = np.maximum(w / w.sum(), 1e-6)
    w = w / w.sum()
    cos = W @ w / (np.linalg.norm(W, axis=1) * np.linalg.norm(w))
    W[int(np.argmax(cos))] = w
    return W


NORMALIZATIONS = ("auto", "defaults", "pareto")
#: with normalization="defaults", an objective in which the defaults are (nearly) the best
#: found is scaled by at least this fraction of the median evaluation's distance to the best
DEFAULTS_SCALE_FLOOR = 0.05


def summarize(
    df: pd.DataFrame,
    objectives: Sequence[str],
    target_weights: Sequence[float] | None = None,
    n_weights: int = 40,
    f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
    normalization: str = "auto",
    default_key: str | None = None,
) -> tuple[pd.DataFrame, pd.Series | None, np.ndarray | None, np.ndarray | None]:
    r"""Mark the Pareto set and the selected solution in an evaluations frame.

    Adds columns ``pareto``, ``selected`` and ``tchebycheff`` (normalised Tchebycheff
    value :math:`\max_i w_i (f_i − z^*_i)/s_i` under the target weights) to ``df`` in
    place. The pick is :func:`tuners.mowoa.select_by_cosine` over the run's
    ``n_weights`` subproblem weight vectors (:func:`run_weight_vectors`, which contain
    the target, so the pick is the Pareto solution with the lowest Tchebycheff value
    under the target weights; ties: lowest weighted sum). :math:`z^*` is the best
    feasible value per objective; the scale :math:`s`:

    * ``f_bounds=(lower, upper)`` given: ``upper − lower`` (004's tolerance values);
    * ``"defaults"``: the defaults' distance to the best, :math:`s_i = f^{def}_i − z^*_i`,
      floored at 5 % of the median feasible evaluation's distance to the best (for
      objectives in which the defaults are about the best), so the defaults score
      :math:`\max_i w_i` and a solution scores lower only if it is better than them in
      every objective that carries weight; as the defaults are evaluated, the pick is
      never worse than them on the tuning seeds — needs the evaluated defaults
      (``default_key``);
    * ``"pareto"``: the Pareto set's range (nadir − ideal). With many objectives nearly
      every evaluation is non-dominated and this range is set by very poor solutions;
    * ``"auto"``: ``"defaults"`` if the defaults were evaluated and feasible, else
      ``"pareto"``.

    Returns (Pareto rows, selected row or None, ideal, ideal + scale); the mode used is
    ``df.attrs["normalization"]``.
    """
    if normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {normalization!r}")
    objectives = list(objectives)
    m = len(objectives)
    w = np.full(m, 1.0 / m) if target_weights is None else np.asarray(target_weights, float)
    w = w / w.sum()
    df["pareto"] = False
    df["selected"] = False
    df["tchebycheff"] = np.nan
    if len(df) == 0:
        return df.iloc[0:0], None, None, None
    feas = df["feasible"].to_numpy(bool)
    if not feas.any():
        return df.iloc[0:0], None, None, None
    F = df.loc[feas, objectives].to_numpy(float)
    idx_feas = np.flatnonzero(feas)
    nd = idx_feas[nondominated(F)]
    ideal = F.min(axis=0)
    F_nd = df.iloc[nd][objectives].to_numpy(float)
    drow = None
    if default_key is not None and "key" in df:
        hit = np.flatnonzero((df["key"] == default_key).to_numpy() & feas)
        drow = int(hit[0]) if len(hit) else None
    mode = normalization
    if f_bounds is not None:
        mode = "bounds"
        nadir = ideal + (np.asarray(f_bounds[1], float) - np.asarray(f_bounds[0], float))
    else:
        if mode == "auto":
            mode = "defaults" if drow is not None else "pareto"
        if mode == "defaults":
            if drow is None:
                raise ValueError("normalization='defaults' needs the evaluated, feasible defaults")
            fd = df.iloc[drow][objectives].to_numpy(float)
            typical = np.median(F, axis=0) - ideal  # robust to the outliers of a search
            floor = DEFAULTS_SCALE_FLOOR * np.maximum(typical, 0.0)
            nadir = ideal + np.maximum(fd - ideal, np.maximum(floor, 1e-12))
        else:
            nadir = np.where(F_nd.max(axis=0) > ideal, F_nd.max(axis=0), F.max(axis=0))
    df.attrs["normalization"] = mode
    df.loc[df.index[nd], "pareto"] = True
    df.loc[df.index[idx_feas], "tchebycheff"] = tchebycheff(F, w, ideal, nadir)
    lam = run_weight_vectors(m, max(int(n_weights), m, 1), w)  # >= one per objective
    pick = nd[select_by_cosine(F_nd, w, ideal, nadir, lam)]
    df.loc[df.index[pick], "selected"] = True
    return df.iloc[nd], df.iloc[pick], ideal, nadir
