r"""Particle swarm optimisation: scalarised PSO (004's MPC-PSO comparator) and MOPSO.

Both are pymoo :class:`~pymoo.core.algorithm.Algorithm` subclasses evaluating one whole
swarm per generation (one parallel batch).

Velocity and position update, inertia-weight PSO (J. Kennedy, R. Eberhart, "Particle
swarm optimization", *Proc. ICNN* 1995; inertia weight: Y. Shi, R. Eberhart, "A
modified particle swarm optimizer", *Proc. IEEE ICEC* 1998), per particle :math:`i`::

    v_i ← w(τ) v_i + c1 r1 ∘ (p_i − x_i) + c2 r2 ∘ (g_i − x_i),   r1, r2 ~ U(0, 1)^n
    v_i ← clip(v_i, −v_max (x_u − x_l), v_max (x_u − x_l))
    x_i ← x_i + v_i;  a component leaving the bounds is put on the bound and its
                      velocity set to 0 ("absorbing walls")

with the constriction-equivalent constants :math:`w = \chi = 0.7298`,
:math:`c_1 = c_2 = \chi \cdot 2.05 = 1.49618` (M. Clerc, J. Kennedy, "The particle
swarm — explosion, stability, and convergence in a multidimensional complex space",
*IEEE Trans. Evol. Comput.* 6(1) 2002; at 40 × 100 evaluations they beat the linearly
decreasing inertia 0.9 → 0.4 with :math:`c_1 = c_2 = 2` of Shi & Eberhart 1999 on the
10-/30-D sphere, ``w=(0.9, 0.4), c1=c2=2`` selects that schedule, :math:`w(\tau) = w_0 +
(w_1 − w_0)\tau` with :math:`\tau` the run progress as in :mod:`tuners.mowoa`),
and :math:`v_\max = 0.2` of the range.

:class:`PSO` minimises one scalarisation of all objectives (004 compares against
"MPC-PSO", a PSO-tuned MPC, without giving its scalarisation): the normalised
Tchebycheff value :math:`\max_i w_i (f_i − z^*_i)/(z^{nad}_i − z^*_i)` (default) or the
weighted sum :math:`\sum_i w_i (f_i − z^*_i)/(z^{nad}_i − z^*_i)` under the target
weights ``weights`` (default: equal). :math:`z^*` is the best value per objective found
so far (feasible evaluations), :math:`z^{nad}` the worst over the non-dominated feasible
evaluations (an archive of at most ``archive_size``); ``f_bounds = (lower, upper)``
fixes the scale :math:`z^{nad} − z^* = upper − lower` instead. The
normalisation moves during the run, so personal and global bests are re-scored every
generation. :math:`p_i` is the particle's best, :math:`g` the swarm's best (global
topology). With one objective it is plain PSO. Constraints: feasibility first (Deb 2000).

:class:`MOPSO` is the multi-objective variant by decomposition (in the spirit of
dMOPSO: S. Zapotecas Martínez, C. A. Coello Coello, "A multi-objective particle swarm
optimizer based on decomposition", *Proc. GECCO* 2011): particle :math:`i` owns weight
vector :math:`\lambda^i`, its personal best is judged by its own Tchebycheff
subproblem, and its social guide :math:`g_i` is the elite of its subproblem, updated
from the neighbourhood exactly as in :class:`tuners.mowoa.MOWOA` (same weight vectors,
reference point, normalisation, elite archive; see that module). pymoo's own MOPSO-CD
was not used: it evaluates a population inside ``_setup`` outside the ask/tell loop
(an extra, unpersisted batch) and ignores constraints.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pymoo.core.algorithm import Algorithm
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.core.sampling import Sampling
from pymoo.util.display.multi import MultiObjectiveOutput
from pymoo.util.display.single import SingleObjectiveOutput

from tuners.mowoa import (
    RANGE_FLOOR,
    DecompositionAlgorithm,
    InitialSampling,
    better,
    crowding_truncate,
    nondominated,
    normalize,
    tchebycheff,
)

__all__ = ["MOPSO", "PSO", "inertia"]


def inertia(tau: float, w: tuple[float, float] | float = (0.9, 0.4)) -> float:
    """Inertia weight at progress ``tau``: linear from ``w[0]`` to ``w[1]`` (or constant)."""
    if isinstance(w, int | float):
        return float(w)
    w0, w1 = w
    return float(w0 + (w1 - w0) * min(1.0, max(0.0, tau)))


def _velocity_step(
    rng: np.random.Generator,
    X: np.ndarray,
    V: np.ndarray,
    P: np.ndarray,
    G: np.ndarray,
    w: float,
    c1: float,
    c2: float,
    v_max: np.ndarray,
    xl: np.ndarray,
    xu: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    r1 = rng.random(X.shape)
    r2 = rng.random(X.shape)
    V = w * V + c1 * r1 * (P - X) + c2 * r2 * (G - X)
    V = np.clip(V, -v_max, v_max)
    X_new = X + V
    out = (X_new < xl) | (X_new > xu)
    V = np.where(out, 0.0, V)
    return np.clip(X_new, xl, xu), V


class PSO(Algorithm):
    """Global-best inertia-weight PSO on a scalarisation of the objectives.

    Args:
        pop_size: swarm size.
        w: inertia: a constant or (start, end) of a linear schedule.
        c1, c2: cognitive and social acceleration constants.
        v_max: velocity bound as a fraction of each variable's range.
        scalarization: ``"tchebycheff"`` or ``"weighted_sum"`` (multi-objective problems).
        weights: target weights of the scalarisation (default: equal).
        f_bounds: (lower, upper) tolerance bounds: normalise by upper − lower.
        archive_size: size of the non-dominated archive that estimates the nadir point.
        initial_X: rows put first in the initial swarm (e.g. the defaults).
        sampling: a pymoo Sampling (overrides ``initial_X``).
        max_gen: generations of the inertia schedule if the termination does not say.
        **kwargs: :class:`pymoo.core.algorithm.Algorithm` options (``seed``, ...).
    """

    def __init__(
        self,
        pop_size: int = 40,
        w: tuple[float, float] | float = 0.7298,
        c1: float = 1.49618,
        c2: float = 1.49618,
        v_max: float = 0.2,
        scalarization: str = "tchebycheff",
        weights: Sequence[float] | None = None,
        f_bounds: tuple[Sequence[float], Sequence[float]] | None = None,
        archive_size: int = 100,
        initial_X: np.ndarray | None = None,
        sampling: Sampling | None = None,
        max_gen: int | None = None,
        output: Any = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(output=output, **kwargs)
        if scalarization not in ("tchebycheff", "weighted_sum"):
            raise ValueError(
                f"scalarization must be 'tchebycheff' or 'weighted_sum', got {scalarization!r}"
            )
        self.pop_size = int(pop_size)
        self.w = w
        self.c1, self.c2 = float(c1), float(c2)
        self.v_max_rate = float(v_max)
        self.scalarization = scalarization
        self.weights = None if weights is None else np.asarray(weights, float)
        self.f_bounds = f_bounds
        self.archive_size = int(archive_size)
        self.sampling = sampling if sampling is not None else InitialSampling(initial_X)
        self.max_gen = max_gen
        self.X: np.ndarray | None = None
        self.V: np.ndarray | None = None
        self.pbest: Population | None = None
        self.nd_archive: Population = Population.empty()
        self.ideal: np.ndarray | None = None
        self.nadir: np.ndarray | None = None
        self.gbest: int = 0

    # ------------------------------------------------------------------ setup
    def _setup(self, problem: Problem, **kwargs: Any) -> None:
        m = problem.n_obj
        if self.output is None:
            self.output = SingleObjectiveOutput() if m == 1 else MultiObjectiveOutput()
        if self.weights is None:
            self.weights = np.full(m, 1.0 / m)
        if self.weights.shape != (m,) or np.any(self.weights < 0) or self.weights.sum() <= 0:
            raise ValueError(f"weights must be {m} non-negative numbers, got {self.weights}")
        self.weights = self.weights / self.weights.sum()
        xl, xu = problem.bounds()
        self._vmax = self.v_max_rate * (xu - xl)

    def _max_gen(self) -> int:
        return DecompositionAlgorithm._max_gen(self)  # same rule as the decomposition family

    def progress(self) -> float:
        return min(1.0, max(0.0, (self.n_iter - 2) / max(1, self._max_gen() - 1)))

    # ---------------------------------------------------------------- scoring
    def scalarize(self, F: np.ndarray) -> np.ndarray:
        """The scalar minimised (one objective: the objective itself)."""
        F = np.atleast_2d(np.asarray(F, float))
        if self.problem.n_obj == 1:
            return F[:, 0]
        if self.scalarization == "tchebycheff":
            return tchebycheff(F, self.weights, self.ideal, self.nadir)
        return normalize(F, self.ideal, self.nadir) @ self.weights

    def _update_reference(self, pop: Population) -> None:
        F, feas = pop.get("F", "feas")
        Ff = F[feas] if np.any(feas) else F
        low = np.min(Ff, axis=0)
        self.ideal = low if self.ideal is None else np.minimum(self.ideal, low)
        merged = Population.merge(self.nd_archive, pop[feas]) if len(self.nd_archive) else pop[feas]
        if len(merged):
            merged = merged[nondominated(merged.get("F"))]
            if len(merged) > self.archive_size:
                AF = merged.get("F")
                merged = merged[
                    crowding_truncate(normalize(AF, AF.min(0), AF.max(0)), self.archive_size)
                ]
            self.nd_archive = merged
        if self.f_bounds is not None:  # fixed scale upper − lower, moving z*
            lo, hi = (np.asarray(b, float) for b in self.f_bounds)
            self.nadir = self.ideal + (hi - lo)
            return
        src = self.nd_archive.get("F") if len(self.nd_archive) else Ff
        nad = np.max(src, axis=0)
        if self.nadir is not None:
            degenerate = nad - self.ideal <= RANGE_FLOOR * np.maximum(1.0, np.abs(nad))
            nad = np.where(degenerate, np.maximum(self.nadir, self.ideal), nad)
        self.nadir = np.maximum(nad, self.ideal)

    def _best_index(self) -> int:
        s = self.scalarize(self.pbest.get("F"))
        cv = self.pbest.get("CV")[:, 0]
        order = np.lexsort((s, cv))
        return int(order[0])

    # ----------------------------------------------------------- pymoo hooks
    def _initialize_infill(self) -> Population:
        pop = self.sampling.do(self.problem, self.pop_size, random_state=self.random_state)
        shape = (self.pop_size, len(self._vmax))
        self.V = self.random_state.uniform(-self._vmax, self._vmax, shape)
        return pop

    def _initialize_advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        self.X = infills.get("X").astype(float).copy()
        self.pbest = Population.create(*[ind.copy() for ind in infills])
        self._update_reference(infills)
        self.gbest = self._best_index()
        self.pop = self.pbest

    def _infill(self) -> Population:
        xl, xu = self.problem.bounds()
        P = self.pbest.get("X").astype(float)
        G = np.tile(P[self.gbest], (self.pop_size, 1))
        w = inertia(self.progress(), self.w)
        X, self.V = _velocity_step(
            self.random_state, self.X, self.V, P, G, w, self.c1, self.c2, self._vmax, xl, xu
        )
        return Population.new("X", X)

    def _advance(self, infills: Population | None = None, **kwargs: Any) -> None:
        self._update_reference(infills)
        s_old = self.scalarize(self.pbest.get("F"))
        s_new = self.scalarize(infills.get("F"))
        cv_old = self.pbest.get("CV")[:, 0]
        cv_new = infills.get("CV")[:, 0]
        for i in range(self.pop_size):
            if better(cv_new[i], s_new[i], cv_old[i], s_old[i]):
                self.pbest[i] = infills[i]
        self.X = infills.get("X").astype(float).copy()
        self.gbest = self._best_index()
        self.pop = self.pbest

    def _set_optimum(self) -> None:
        self.opt = self.pbest[[self.gbest]]


class MOPSO(DecompositionAlgorithm):
    """Multi-objective PSO by Tchebycheff decomposition (see the module docstring).

    Args:
        pop_size: particles = subproblems.
        w, c1, c2, v_max: as :class:`PSO` (defaults 0.7298, 1.49618, 1.49618, 0.2).
        **kwargs: :class:`tuners.mowoa.DecompositionAlgorithm` options (``n_neighbors``,
            ``prob_neighbor``, ``n_replace``, ``archive_size``, ``initial_X``,
            ``f_bounds``, ``max_gen``) and pymoo ``Algorithm`` options.
    """

    def __init__(
        self,
        pop_size: int = 40,
        w: tuple[float, float] | float = 0.7298,
        c1: float = 1.49618,
        c2: float = 1.49618,
        v_max: float = 0.2,
        **kwargs: Any,
    ) -> None:
        super().__init__(pop_size=pop_size, **kwargs)
        self.w = w
        self.c1, self.c2 = float(c1), float(c2)
        self.v_max_rate = float(v_max)
        self.V: np.ndarray | None = None
        self.pbest: Population | None = None

    def _init_state(self, infills: Population, X, F, CV) -> None:
        xl, xu = self.problem.bounds()
        self._vmax = self.v_max_rate * (xu - xl)
        self.V = self.random_state.uniform(-self._vmax, self._vmax, self.X.shape)
        self.pbest = Population.create(*[ind.copy() for ind in infills])
        self.PX, self.PF, self.PCV = X.copy(), F.copy(), CV.copy()

    def _move(self) -> np.ndarray:
        xl, xu = self.problem.bounds()
        P = self.PX
        w = inertia(self.progress(), self.w)
        X, self.V = _velocity_step(
            self.random_state,
            self.X,
            self.V,
            P,
            self.leaders(),
            w,
            self.c1,
            self.c2,
            self._vmax,
            xl,
            xu,
        )
        return X

    def _after_move(self, infills: Population, X, F, CV) -> None:
        g_old = self.scores(self.PF, self.ref_dirs)
        g_new = self.scores(F, self.ref_dirs)
        for i in range(self.pop_size):
            if better(CV[i], g_new[i], self.PCV[i], g_old[i]):
                self.pbest[i] = infills[i]
                self.PX[i], self.PF[i], self.PCV[i] = X[i], F[i], CV[i]
