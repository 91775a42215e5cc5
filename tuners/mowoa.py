r"""Multi-objective whale optimisation (MOWOA) by Tchebycheff decomposition — paper 004 §3.

Paper 004 (Wang, Wang, Chen, *Optimized MPC using a multi-objective whale optimization
algorithm for urban rail train tracking control*) tunes its controller with a whale
optimisation algorithm that (i) moves whales by the three WOA behaviours with an
*encircle probability*, (ii) shrinks the search by a nonlinear, natural-constant based
convergence factor with a *rate factor* (1.72 in 004), (iii) decomposes the objectives
by Tchebycheff scalarisation over weight vectors with a reference point, (iv) keeps
elites, and (v) picks the final solution by cosine similarity to a user's target weight
vector. Its formulas were lost in the text extraction; the WOA moves below are the
standard ones of

    S. Mirjalili, A. Lewis, "The Whale Optimization Algorithm", *Advances in Engineering
    Software* 95 (2016) 51–67, eqs. (2.1)–(2.8),

and the decomposition is the Tchebycheff approach of MOEA/D,

    Q. Zhang, H. Li, "MOEA/D: A multiobjective evolutionary algorithm based on
    decomposition", *IEEE Trans. Evol. Comput.* 11(6) (2007) 712–731, eq. (2).

WOA moves (Mirjalili & Lewis 2016), for whale :math:`i` at position :math:`X_i`, its
leader :math:`X^*` and iteration progress :math:`\tau = t / T \in [0, 1)`::

    A = 2 a r1 − a,   C = 2 r2,              r1, r2 ~ U(0, 1)            (2.3), (2.4)
    encircle (p < p_e, |A| < 1):  D = |C X* − X_i|,      X_i ← X* − A D     (2.1), (2.2)
    search   (p < p_e, |A| ≥ 1):  D = |C X_rand − X_i|,  X_i ← X_rand − A D (2.7), (2.8)
    spiral   (p ≥ p_e):           D' = |X* − X_i|,
                                  X_i ← D' e^{b l} cos(2π l) + X*,  l ~ U(−1, 1)  (2.5)

with :math:`b = 1` (004) and the encircle probability :math:`p_e = 0.6` (004; the
original WOA uses 0.5). ``r1`` is one scalar per whale so that the test :math:`|A| < 1`
is unambiguous (the paper writes A as a vector but tests its magnitude); ``r2`` (hence
``C``) is drawn per dimension (``vector_c=True``, the vector form of eq. 2.4) or per
whale.

Choices where 004 is silent (all configurable; the reasons and the measurements behind
them are in ``docs/design/mowoa.md``): the convergence factor
:math:`a(\tau) = 2\bigl(1 − ((e^{\tau} − 1)/(e − 1))^{k}\bigr)`, :math:`k = 1.72`, over
the move generations (``convergence="linear"`` restores WOA); one weight vector per
whale (evenly spaced, Das–Dennis or Riesz s-energy, floored at 1e-6); the normalised
Tchebycheff value :math:`\max_i \lambda_i (f_i − z^*_i)/(z^{nad}_i − z^*_i)` with
:math:`z^*` the best feasible value so far and :math:`z^{nad}` the worst over the elite
archive (or ``f_bounds``); per-subproblem elites as leaders with the MOEA/D replacement
rule and a crowding-truncated archive of feasible non-dominated solutions (the result,
``res.opt``); feasibility first (Deb 2000); clipping to the bounds; the final pick by
cosine similarity of the subproblem weights to the target (:func:`select_by_cosine`).
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Sequence
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.core.sampling import Sampling
from pymoo.util.display.multi import MultiObjectiveOutput
from pymoo.util.display.single import SingleObjectiveOutput
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

RANGE_FLOOR = 1e-12
WEIGHT_FLOOR = 1e-6

__all__ = [
    "MOWOA",
    "DecompositionAlgorithm",
    "InitialSampling",
    "convergence_factor",
    "crowding_truncate",
    "nondominated",
    "normalize",
    "select_by_cosine",
    "tchebycheff",
    "weight_vectors",
]


# --------------------------------------------------------------------------- helpers
@lru_cache(maxsize=32)
def _weight_vectors_cached(n_obj: int, n: int, seed: int) -> tuple[tuple[float, ...], ...]:
    if n_obj == 1:
        w = np.ones((n, 1))
    elif n_obj == 2:
        t = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
        w = np.column_stack([t, 1.0 - t])
    else:
        from pymoo.util.ref_dirs import get_reference_directions

        h = 1
        while math.comb(h + n_obj - 1, n_obj - 1) < n:
            h += 1
        if math.comb(h + n_obj - 1, n_obj - 1) == n:
            w = get_reference_directions("das-dennis", n_obj, n_partitions=h)
        else:
            path = _energy_cache_path(n_obj, n, seed)
            w = _load_directions(path, (n, n_obj))
            if w is None:
                w = get_reference_directions("energy", n_obj, n, seed=seed)
                _store_directions(path, np.asarray(w, float))
    w = np.maximum(np.asarray(w, float), WEIGHT_FLOOR)
    w = w / w.sum(axis=1, keepdims=True)
    return tuple(tuple(float(v) for v in row) for row in w)


def _energy_cache_path(n_obj: int, n: int, seed: int) -> Path:
    """Where the Riesz s-energy directions of ``(n_obj, n, seed)`` are kept between
    processes: ``$TRAIN_ENVS_CACHE_DIR`` (default ``$XDG_CACHE_HOME/train-envs``, else
    ``~/.cache/train-envs``), one ``.npy`` file per pymoo version (the directions are
    pymoo's deterministic output for the seed; computing them takes seconds)."""
    root = os.environ.get("TRAIN_ENVS_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "train-envs"
    )
    try:
        tag = version("pymoo")
    except PackageNotFoundError:  # pragma: no cover - pymoo is a dependency
        tag = "unknown"
    return Path(root) / "weight_vectors" / f"energy-{n_obj}-{n}-s{seed}-pymoo{tag}.npy"


def _load_directions(path: Path, shape: tuple[int, int]) -> np.ndarray | None:
    """The directions stored at ``path`` (a plain ``.npy`` array, read without
    pickle), or None where the file is missing, unreadable, not a plain array or not
    ``shape`` rows of finite non-negative numbers."""
    try:
        with open(path, "rb") as fh:
            w = np.load(fh, allow_pickle=False)
            if not isinstance(w, np.ndarray):  # (an .npz archive)
                return None
    except Exception:  # noqa: BLE001 - whatever cannot be read is computed again
        return None
    if w.shape != shape or w.dtype != np.float64 or not np.isfinite(w).all() or (w < 0).any():
        return None
    return w


def _store_directions(path: Path, w: np.ndarray) -> None:
    """Write ``w`` to ``path`` atomically (a temporary file renamed); nothing where the
    directory cannot be written."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as fh:
            np.save(fh, w, allow_pickle=False)
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.remove(tmp)


def weight_vectors(n_obj: int, n: int, seed: int = 1) -> np.ndarray:
    """``n`` weight vectors on the unit simplex (rows sum to 1, components ≥ 1e-6).

    Two objectives: evenly spaced; more: Das–Dennis if ``n`` is a simplex-lattice size,
    else Riesz s-energy directions (pymoo, deterministic for a given ``seed``; kept on
    disk between processes, :func:`_energy_cache_path`).
    """
    if n < 1 or n_obj < 1:
        raise ValueError(f"need n >= 1 and n_obj >= 1, got n={n}, n_obj={n_obj}")
    return np.array(_weight_vectors_cached(int(n_obj), int(n), int(seed)))


def normalize(F: np.ndarray, ideal: np.ndarray, nadir: np.ndarray) -> np.ndarray:
    """:math:`f' = (f − z^*)/(z^{nad} − z^*)` with the range floored at 1e-12."""
    return (np.asarray(F, float) - ideal) / np.maximum(nadir - ideal, RANGE_FLOOR)


def tchebycheff(
    F: np.ndarray, weights: np.ndarray, ideal: np.ndarray, nadir: np.ndarray | None = None
) -> np.ndarray:
    r"""Tchebycheff value :math:`g = \max_i \lambda_i (f_i − z^*_i)/(z^{nad}_i − z^*_i)`.

    ``F`` is (n, m); ``weights`` is (m,) or (n, m) (row-wise pairing). Without ``nadir``
    no normalisation is applied. The difference is not taken in absolute value so that
    a point better than the reference (possible on held-out data) scores lower; for
    :math:`z^*` the ideal point this equals Zhang & Li's :math:`\max_i \lambda_i|f_i − z_i|`.
    """
    F = np.atleast_2d(np.asarray(F, float))
    Fn = F - ideal if nadir is None else normalize(F, ideal, nadir)
    return np.max(np.asarray(weights, float) * Fn, axis=-1)


def select_by_cosine(
    F: np.ndarray,
    target: Sequence[float],
    ideal: np.ndarray,
    nadir: np.ndarray,
    weights: np.ndarray | None = None,
) -> int:
    r"""Index of the row of ``F`` picked for the target weights (004 §3.2).

    Among the subproblem weight vectors :math:`\lambda^j` (``weights``; default
    :func:`weight_vectors` ``(m, 100)``) the one with the largest cosine similarity
    :math:`\cos(\lambda^j, w)` to the target :math:`w` is taken, and the row minimising
    that subproblem's Tchebycheff value :math:`g(x \mid \lambda^j, z^*)` — the
    subproblem's elite — is returned. Ties (several equally close weight vectors, or
    several rows with the same value) go to the row with the smaller Tchebycheff value
    under :math:`w` itself, then the smaller :math:`w`-weighted sum of normalised
    objectives, then the lower index.
    """
    F = np.atleast_2d(np.asarray(F, float))
    m = F.shape[1]
    w = np.asarray(target, float)
    if w.shape != (m,) or np.any(w < 0) or not np.any(w > 0):
        raise ValueError(
            f"target weights must be {m} non-negative numbers, not all 0; got {target}"
        )
    w = w / w.sum()
    lam = weight_vectors(m, 100) if weights is None else np.atleast_2d(np.asarray(weights, float))
    cos = np.round(lam @ w / (np.linalg.norm(lam, axis=1) * np.linalg.norm(w)), 9)
    g_w = np.round(tchebycheff(F, w, ideal, nadir), 12)
    ws = normalize(F, ideal, nadir) @ w
    picks = set()
    for j in np.flatnonzero(cos == cos.max()):
        g = np.round(tchebycheff(F, lam[j], ideal, nadir), 12)
        picks.add(int(np.lexsort((np.arange(len(F)), ws, g_w, g))[0]))
    cand = np.array(sorted(picks))
    return int(cand[np.lexsort((cand, ws[cand], g_w[cand]))[0]])


def nondominated(F: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated rows of ``F`` (minimisation), in ascending order."""
    F = np.atleast_2d(np.asarray(F, float))
    if len(F) == 0:
        return np.zeros(0, dtype=int)
    if F.shape[1] == 1:
        return np.array([int(np.argmin(F[:, 0]))])
    idx = NonDominatedSorting().do(F, only_non_dominated_front=True)
    return np.sort(np.asarray(idx, dtype=int))


def _crowding(F: np.ndarray) -> np.ndarray:
    n, m = F.shape
    d = np.zeros(n)
    if n <= 2:
        return np.full(n, np.inf)
    for k in range(m):
        order = np.argsort(F[:, k], kind="stable")
        f = F[order, k]
        rng = f[-1] - f[0]
        d[order[0]] = d[order[-1]] = np.inf
        if rng > 0:
            d[order[1:-1]] += (f[2:] - f[:-2]) / rng
    return d


def crowding_truncate(F: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` rows kept by removing the most crowded row one at a time.

    Crowding distance of Deb et al. (NSGA-II, 2002), recomputed after every removal
    (deterministic: ties go to the lowest index).
    """
    keep = np.arange(len(F))
    while len(keep) > k:
        d = _crowding(F[keep])
        keep = np.delete(keep, int(np.argmin(d)))
    return keep


def convergence_factor(
    tau: float, kind: str = "exp", rate: float = 1.72, a_max: float = 2.0
) -> float:
    r"""WOA convergence factor at progress ``tau`` ∈ [0, 1].

    ``"exp"`` (our reading of 004): :math:`a = a_\max(1 − ((e^\tau − 1)/(e − 1))^{k})`;
    ``"linear"`` (Mirjalili & Lewis 2016): :math:`a = a_\max(1 − \tau)`.
    """
    tau = min(1.0, max(0.0, float(tau)))
    if kind == "linear":
        return a_max * (1.0 - tau)
    if kind == "exp":
        return a_max * (1.0 - ((math.exp(tau) - 1.0) / (math.e - 1.0)) ** rate)
    raise ValueError(f"convergence must be 'exp' or 'linear', got {kind!r}")


def bounce_back(
    X: np.ndarray, X_old: np.ndarray, xl: np.ndarray, xu: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Bounce-back repair: a component beyond a bound is put at a uniformly random point
    between the old position and that bound (Price, Storn & Lampinen, *Differential
    Evolution*, Springer 2005, §4.4). Random numbers are drawn for every component.
    """
    r = rng.random(X.shape)
    X = np.where(X < xl, X_old - r * (X_old - xl), X)
    X = np.where(X > xu, X_old + r * (xu - X_old), X)
    return np.clip(X, xl, xu)


def better(cv_a: float, g_a: float, cv_b: float, g_b: float) -> bool:
    """Feasibility-first comparison (Deb 2000): is (cv_a, g_a) strictly better?"""
    if cv_a > 0.0 or cv_b > 0.0:
        return cv_a < cv_b
    return g_a < g_b


class InitialSampling(Sampling):
    """Uniform random sampling in the bounds; the given rows (e.g. defaults) come first.

    The random matrix is always drawn in full so that the random stream does not depend
    on ``X0``.
    """

    def __init__(self, X0: np.ndarray | Sequence[Sequence[float]] | None = None) -> None:
        super().__init__()
        self.X0 = None if X0 is None else np.atleast_2d(np.asarray(X0, float))

    def _do(self, problem: Problem, n_samples: int, *args: Any, random_state=None, **kwargs):
        xl, xu = problem.bounds()
        X = xl + (xu - xl) * random_state.random((n_samples, problem.n_var))
        if self.X0 is not None:
            k = min(len(self.X0), n_samples)
            X[:k] = np.clip(self.X0[:k], xl, xu)
        return X


# ------------------------------------------------------------ decomposition base
class DecompositionAlgorithm(Algorithm):
    """Generation-synchronous decomposition framework shared by MOWOA and MOPSO.

    Subclasses implement :meth:`_move` (new positions from ``self.X``) and may extend
    :meth:`_init_state` / :meth:`_after_move`. One generation evaluates one new position
    per subproblem, so a whole generation is one parallel batch. See the module
    docstring for the weight vectors, normalisation, elite update and archive.
    """

    def __init__(
        self,
        pop_size: int = 40,
        ref_dirs: np.ndarray | None = None,
        n_neighbors: int | None = None,
        prob_neighbor: float = 0.9,
        n_replace: int = 2,
        archive_size: int | None = None,
        sampling: Sampling | None = None,
        initial_X: np.ndarray | None = None,
        f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
        max_gen: int | None = None,
        bounds_repair: str = "clip",
        normalization: str = "archive",
        output: Any = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(output=output, **kwargs)
        if bounds_repair not in ("bounce", "clip"):
            raise ValueError(f"bounds_repair must be 'bounce' or 'clip', got {bounds_repair!r}")
        if normalization not in ("archive", "population", "none"):
            raise ValueError(
                f"normalization must be 'archive', 'population' or 'none', got {normalization!r}"
            )
        self.bounds_repair = bounds_repair
        self.normalization = normalization
        self.pop_size = int(pop_size)
        self.ref_dirs = None if ref_dirs is None else np.asarray(ref_dirs, float)
        self.n_neighbors = n_neighbors
        self.prob_neighbor = float(prob_neighbor)
        self.n_replace = int(n_replace)
        self.archive_size = archive_size
        self.sampling = sampling if sampling is not None else InitialSampling(initial_X)
        self.f_bounds = f_bounds
        self.max_gen = max_gen
        self.elites: Population | None = None
        self.elite_archive: Population = Population.empty()
        self.X: np.ndarray | None = None
        # array mirrors of the elites (EX, EF, ECV) and of the archive (AX, AF)
        self.EX = self.EF = self.ECV = None
        self.AX = self.AF = np.zeros((0, 0))
        self.ideal: np.ndarray | None = None
        self.nadir: np.ndarray | None = None
        self._local: np.ndarray | None = None

    # ---------------------------------------------------------------- setup
    def _setup(self, problem: Problem, **kwargs: Any) -> None:
        m = problem.n_obj
        if self.output is None:
            self.output = MultiObjectiveOutput() if m > 1 else SingleObjectiveOutput()
        if self.ref_dirs is None:
            self.ref_dirs = weight_vectors(m, self.pop_size)
        if self.ref_dirs.shape[1] != m:
            raise ValueError(f"ref_dirs have {self.ref_dirs.shape[1]} columns, problem has {m}")
        self.pop_size = len(self.ref_dirs)
        n_nb = self.n_neighbors or max(2, math.ceil(0.2 * self.pop_size))
        n_nb = min(int(n_nb), self.pop_size)
        d = np.linalg.norm(self.ref_dirs[:, None, :] - self.ref_dirs[None, :, :], axis=2)
        self.neighbors = np.argsort(d, axis=1, kind="stable")[:, :n_nb]
        if self.archive_size is None:
            self.archive_size = self.pop_size
        if self.f_bounds is not None:
            lo, hi = (np.asarray(b, float) for b in self.f_bounds)
            if lo.shape != (m,) or hi.shape != (m,) or np.any(hi <= lo):
                raise ValueError("f_bounds must be (lower, upper) with lower < upper per objective")

    def _max_gen(self) -> int:
        if self.max_gen is not None:
            return int(self.max_gen)
        term = self.termination
        if hasattr(term, "n_max_gen") and math.isfinite(term.n_max_gen):
            return int(term.n_max_gen)
        if hasattr(term, "n_max_evals") and math.isfinite(term.n_max_evals):
            return max(2, int(term.n_max_evals) // self.pop_size)
        raise ValueError(
            f"{type(self).__name__} needs the number of generations for its schedule: use an "
            "('n_gen', G) or ('n_eval', E) termination or pass max_gen"
        )

    def progress(self) -> float:
        """τ = (gen − 2)/(gens − 1) ∈ [0, 1) for the move generations 2..gens."""
        return min(1.0, max(0.0, (self.n_iter - 2) / max(1, self._max_gen() - 1)))

    # ------------------------------------------------------------ scoring
    @staticmethod
    def _arrays(pop: Population) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(X, F, CV, feasible) of a population in one pass (``Population.get`` is slow)."""
        X, F, CV = pop.get("X", "F", "CV")
        cv = np.asarray(CV, float).reshape(len(pop), -1)[:, 0]
        return np.asarray(X, float), np.asarray(F, float), cv, cv <= 0.0

    def _refresh_reference(self, F_new: np.ndarray, feas_new: np.ndarray) -> None:
        if self.f_bounds is not None:  # 004's tolerance bounds: fixed scale, moving z*
            lo, hi = (np.asarray(b, float) for b in self.f_bounds)
            self.nadir = self.ideal + (hi - lo)
            return
        if self.normalization == "none":
            self.nadir = self.ideal + 1.0
            return
        if self.normalization == "archive" and len(self.AF) > 0:
            nad = np.max(self.AF, axis=0)
            if self.nadir is not None:
                degenerate = nad - self.ideal <= RANGE_FLOOR * np.maximum(1.0, np.abs(nad))
                nad = np.where(degenerate, np.maximum(self.nadir, self.ideal), nad)
            self.nadir = np.maximum(nad, self.ideal)
            return
        F = np.vstack([self.EF, F_new]) if self.EF is not None else F_new
        feas = np.concatenate([self.ECV <= 0, feas_new]) if self.EF is not None else feas_new
        F = F[feas] if np.any(feas) else F
        self.nadir = np.maximum(np.max(F, axis=0), self.ideal)

    def _update_ideal(self, F: np.ndarray, feas: np.ndarray) -> None:
        F = F[feas] if np.any(feas) else F
        low = np.min(F, axis=0)
        self.ideal = low if self.ideal is None else np.minimum(self.ideal, low)

    def scores(self, F: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Tchebycheff values of ``F`` rows under ``weights`` (current normalisation)."""
        F = np.atleast_2d(np.asarray(F, float))
        if self.problem.n_obj == 1:
            return np.broadcast_to(F[:, 0], (max(len(F), len(np.atleast_2d(weights))),))
        return tchebycheff(F, weights, self.ideal, self.nadir)

    def _update_archive(
        self, pop: Population, X: np.ndarray, F: np.ndarray, feas: np.ndarray
    ) -> None:
        pop, X, F = pop[feas], X[feas], F[feas]
        if len(self.AF):
            pop = Population.merge(self.elite_archive, pop)
            X, F = np.vstack([self.AX, X]), np.vstack([self.AF, F])
        if len(F) == 0:
            return
        # drop exact duplicates in objective and decision space (keep the first)
        _, first = np.unique(np.hstack([F, X]), axis=0, return_index=True)
        keep = np.sort(first)
        keep = keep[nondominated(F[keep])]
        if len(keep) > self.archive_size:
            Fk = F[keep]
            keep = keep[crowding_truncate(normalize(Fk, Fk.min(0), Fk.max(0)), self.archive_size)]
        self.elite_archive, self.AX, self.AF = pop[keep], X[keep], F[keep]

    def _replace_elites(
        self, infills: Population, X: np.ndarray, F: np.ndarray, CV: np.ndarray
    ) -> None:
        order = self.random_state.permutation(len(infills))
        for i in order:
            pool = self.neighbors[i] if self._local[i] else np.arange(self.pop_size)
            pool = pool[self.random_state.permutation(len(pool))]
            g_off = self.scores(F[i][None, :], self.ref_dirs[pool])
            g_el = self.scores(self.EF[pool], self.ref_dirs[pool])
            count = 0
            for k, j in enumerate(pool):
                if better(CV[i], g_off[k], self.ECV[j], g_el[k]):
                    self.elites[j] = infills[i]
                    self.EX[j], self.EF[j], self.ECV[j] = X[i], F[i], CV[i]
                    count += 1
                    if count >= self.n_replace:
                        break

    # ------------------------------------------------------------ pymoo hooks
    def _initialize_infill(self) -> Population:
        return self.sampling.do(self.problem, self.pop_size, random_state=self.random_state)

    def _initialize_advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        X, F, CV, feas = self._arrays(infills)
        self.X = X.copy()
        self.elites = Population.create(*[ind.copy() for ind in infills])
        self.EX, self.EF, self.ECV = X.copy(), F.copy(), CV.copy()
        self.AX, self.AF = np.zeros((0, X.shape[1])), np.zeros((0, F.shape[1]))
        self._update_ideal(F, feas)
        self._update_archive(infills, X, F, feas)
        self._refresh_reference(F, feas)
        self._local = np.ones(self.pop_size, dtype=bool)
        self._init_state(infills, X, F, CV)
        self.pop = self.elites

    def _infill(self) -> Population:
        N = self.pop_size
        self._local = (
            self.random_state.random(N) < self.prob_neighbor
            if self.problem.n_obj > 1
            else np.zeros(N, dtype=bool)
        )
        X = self._move()
        xl, xu = self.problem.bounds()
        if self.bounds_repair == "clip":
            X = np.clip(X, xl, xu)
        else:
            X = bounce_back(X, self.X, xl, xu, self.random_state)
        return Population.new("X", X)

    def _advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        X, F, CV, feas = self._arrays(infills)
        self._update_ideal(F, feas)
        self._update_archive(infills, X, F, feas)
        self._refresh_reference(F, feas)
        self._replace_elites(infills, X, F, CV)
        self._after_move(infills, X, F, CV)
        self.X = X.copy()
        self.pop = self.elites

    def _set_optimum(self) -> None:
        if len(self.elite_archive):
            self.opt = self.elite_archive.copy()
        else:
            self.opt = self.elites[[int(np.argmin(self.ECV))]]

    # ------------------------------------------------------------ subclass API
    def leaders(self) -> np.ndarray:
        """X* per whale/particle: its subproblem elite (one objective: the global best)."""
        if self.problem.n_obj == 1:
            best = self.AX[0] if len(self.AX) else self.EX[int(np.argmin(self.ECV))]
            return np.tile(best, (self.pop_size, 1))
        return self.EX.copy()

    def pool(self, i: int) -> np.ndarray:
        return self.neighbors[i] if self._local[i] else np.arange(self.pop_size)

    def _init_state(
        self, infills: Population, X: np.ndarray, F: np.ndarray, CV: np.ndarray
    ) -> None:
        """Hook after the initial evaluation (arrays of the initial population)."""

    def _after_move(
        self, infills: Population, X: np.ndarray, F: np.ndarray, CV: np.ndarray
    ) -> None:
        """Hook after each evaluated generation (arrays of the new positions)."""

    def _move(self) -> np.ndarray:
        raise NotImplementedError


# ---------------------------------------------------------------------- MOWOA
class MOWOA(DecompositionAlgorithm):
    """Multi-objective whale optimisation algorithm of paper 004 (see module docstring).

    Args:
        pop_size: number of whales = number of Tchebycheff subproblems (004: 40).
        p_encircle: probability of the encircle/search branch (004: 0.6; WOA: 0.5).
        b: spiral shape constant (004, WOA: 1).
        rate: rate factor k of the convergence factor (004: 1.72).
        convergence: ``"exp"`` (004, our reading) or ``"linear"`` (WOA).
        a_max: initial convergence factor (WOA: 2).
        vector_c: draw C per dimension (True) or one per whale.
        n_neighbors, prob_neighbor, n_replace: neighbourhood size (default 20 % of the
            population, at least 2), probability of the local pool, replacements per new
            position (MOEA/D defaults 0.9, 2).
        archive_size: elite archive size (default: ``pop_size``).
        initial_X: rows put first in the initial population (e.g. the defaults).
        sampling: a pymoo Sampling for the initial population (overrides ``initial_X``).
        ref_dirs: the weight vectors (default :func:`weight_vectors`).
        f_bounds: (lower, upper) tolerance bounds: normalise by upper − lower.
        normalization: ``"archive"`` (default), ``"population"`` or ``"none"``.
        bounds_repair: ``"clip"`` (default) or ``"bounce"``.
        max_gen: generations of the schedule if the termination does not give them.
        **kwargs: :class:`pymoo.core.algorithm.Algorithm` options (``seed``, ...).
    """

    def __init__(
        self,
        pop_size: int = 40,
        p_encircle: float = 0.6,
        b: float = 1.0,
        rate: float = 1.72,
        convergence: str = "exp",
        a_max: float = 2.0,
        vector_c: bool = True,
        **kwargs: Any,
    ) -> None:
        super().__init__(pop_size=pop_size, **kwargs)
        if not 0.0 <= p_encircle <= 1.0:
            raise ValueError(f"p_encircle must lie in [0, 1], got {p_encircle}")
        convergence_factor(0.5, convergence, rate, a_max)  # validates ``convergence``
        self.p_encircle = float(p_encircle)
        self.b = float(b)
        self.rate = float(rate)
        self.convergence = convergence
        self.a_max = float(a_max)
        self.vector_c = bool(vector_c)

    def convergence_factor(self) -> float:
        """a(τ) of the current generation (see :func:`convergence_factor`)."""
        return convergence_factor(self.progress(), self.convergence, self.rate, self.a_max)

    def _move(self) -> np.ndarray:
        rng = self.random_state
        a = self.convergence_factor()
        X = self.X
        N, n = X.shape
        lead = self.leaders()
        X_new = np.empty_like(X)
        for i in range(N):
            # the same random numbers are drawn whatever the branch (stable stream)
            r1 = rng.random()
            r2 = rng.random(n) if self.vector_c else np.full(n, rng.random())
            p = rng.random()
            l = rng.uniform(-1.0, 1.0)  # noqa: E741
            pool = self.pool(i)
            j = int(pool[rng.integers(len(pool))])
            A = 2.0 * a * r1 - a
            C = 2.0 * r2
            if p < self.p_encircle:
                # |A| < 1: encircling prey, eqs. (2.1)-(2.2), around the leader;
                # |A| >= 1: search for prey, eqs. (2.7)-(2.8), around a random whale
                target = lead[i] if abs(A) < 1.0 else X[j]
                D = np.abs(C * target - X[i])
                X_new[i] = target - A * D
            else:  # bubble-net spiral, eq. (2.5)
                D = np.abs(lead[i] - X[i])
                X_new[i] = D * math.exp(self.b * l) * math.cos(2.0 * math.pi * l) + lead[i]
        return X_new
