r"""Paper 002: adaptive MPC for cruise control of an n-car train, and its non-adaptive twin.

Xu et al. (2019), "Adaptive model predictive control for cruise control of high-speed
trains with time-varying parameters".

* ``"adaptive_mpc"`` (:class:`AdaptiveCruiseMPC`): gradient estimator of the one-step
  model (002 eq. 12–16, :class:`GradientEstimator`) + excitation bound as an input
  constraint (eq. 17, 26–28, :func:`excitation_box`) + MPC on the estimated model
  (eq. 18–25, 29–34);
* ``"mpc002"`` (:class:`NominalCruiseMPC`): the same MPC on the nominal model with the
  estimate frozen (λ = 0, no excitation bound), 002's comparator (its ref. [15]).
  Neither has a disturbance observer or integral action.

**Model (002 eq. 3–8).** ``ξ̇_j = v_j − v_{j+1}``,
``m_i v̇_i = u_i + kξ_{i−1} − kξ_i − R_i(v_i) − m_i gθ/1000`` with ``R_i = m_i(c_0 +
c_1 v_i)`` and the aero term ``(Σ m_j) c_2 v_1²`` on the lead car (plus a coupler
damping when the train has one), Davis part linearised about v_r (slope in the matrix,
re-linearised when v_r moved more than ``relinearise_mps``; the rest a per-stage affine
term), exact ZOH: ``x(k+1) = A x + B u + d(k)``, ``x = [ξ (mm), v (m/s)]``, u in kN
(:func:`~train_envs.controllers.models.coupled_cars_relative_continuous`).

**Estimate (eq. 12–16, with an affine column).** In error coordinates about the
reference point ``(x_r, û_ff)``, ``x_r = [0; v_r 1]``, ``û_ff`` the input that keeps the
estimated model on the reference::

    x̂(k+1) = A x + B u + d(k) + ΔΘ̂ X,   X = [x − x_r; u − û_ff; c_b]
    ΔΘ̂ ← ΔΘ̂ + λ x̃(k+1) Xᵀ                (stable while λ‖X‖² < 2 − α, eq. 17)

The constant ``c_b`` (``bias_regressor``) lets the estimate carry the running-resistance
offset that the time-varying c_0, c_1, c_2 cause; ``R̂_dev = −B_v⁻¹ c_b ΔΘ̂_{v,end}``
is reported in ``info``.

**Excitation bound (eq. 26–28).** ``‖u(k) − û_ff‖ < ρ = sqrt((2−α)/λ − ‖e‖² − c_b²)``,
replaced by its inscribed box on the first move only, intersected with the force box
and the rate window; it enters the QP as a hard per-call bound on an input copy
appended to the MPC state.

**MPC (eq. 18–25, 29–34).** On the estimated model minimise
``Σ_{i=1}^{N_p} q_v‖v_i − v_{r,i}1‖² + q_ξ‖ξ_i‖² + Σ_{i=0}^{N_c−1} r_u‖u_i − û_ff,i‖² +
r_Δ‖Δu_i‖²`` (r_Δ small, ours) subject to the hard force box (eq. 29), a hard rate limit
(ours), the soft boxes ``0 ≤ v ≤ v_lim`` (eq. 30) and ``|ξ_j| ≤ 0.02 m`` (eq. 33) and the
excitation box, solved by :class:`~train_envs.mpc.LinearMPC`. The
estimated matrices are pushed into the QP only when they moved by more than
``model_refresh_tol`` and with every re-linearisation; in between the affine term
evaluates the current estimate at the reference point. Design notes and measurements:
``docs/design/adaptive_mpc.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from train_envs.controllers._common import per_car_davis
from train_envs.controllers.base import ControlContext, Controller, Observation, TunableParam
from train_envs.controllers.models import (
    coupled_cars_relative_continuous,
    discretise,
    gradient_accel,
    resistance_offset_accel,
)
from train_envs.mpc import LinearMPC
from train_envs.mpc.blas import single_thread_blas
from train_envs.plants.lookup import gradient_table
from train_envs.plants.physics import davis_slope
from train_envs.validation import check_range

__all__ = [
    "AdaptiveCruiseMPC",
    "AdaptiveMPCConfig",
    "GradientEstimator",
    "NominalCruiseMPC",
    "excitation_box",
    "feasible_target",
]


# ---------------------------------------------------------------------------------------
# estimator
# ---------------------------------------------------------------------------------------
class GradientEstimator:
    r"""Gradient estimator of a linear-in-parameters one-step model (002 eq. 12–17).

    Model :math:`\hat y(k+1) = \hat\Theta X(k)` (plus an optional known ``offset``),
    update :math:`\hat\Theta \leftarrow \hat\Theta + \lambda\,\tilde y\, X^\top` with
    :math:`\tilde y = y(k+1) - \hat y(k+1)` (eq. 16, the negative gradient of
    :math:`\lVert\tilde y\rVert^2/2`). For constant true Θ the parameter error obeys
    :math:`\tilde\Theta^+ = \tilde\Theta (I - \lambda X X^\top)`, which does not grow iff
    :math:`\lambda\lVert X\rVert^2 \le 2`; the paper keeps
    :math:`\lVert X\rVert^2 < (2-\alpha)/\lambda` (eq. 17) and with persistent
    excitation Θ̂ converges to Θ. If a regressor violates the bound anyway, the step is
    shrunk to :math:`\lambda_{eff} = (2-\alpha)/\lVert X\rVert^2` (so
    :math:`\lambda_{eff}\lVert X\rVert^2 = 2-\alpha`) and ``last_clipped`` is set.

    Args:
        theta0: initial estimate, shape ``(n_out, n_reg)``.
        lam: adaptation gain λ >= 0 (0 freezes the estimate).
        alpha: margin α in (0, 2) of the excitation bound.
    """

    def __init__(self, theta0: np.ndarray, lam: float, alpha: float = 0.5) -> None:
        th = np.array(theta0, dtype=float)
        if th.ndim != 2 or not np.all(np.isfinite(th)):
            raise ValueError(f"theta0 must be a finite 2-D array, got shape {th.shape}")
        self.theta = th
        self.lam = _check_lam(lam)
        self.alpha = _check_alpha(alpha)
        self.last_clipped = False
        self.last_lam_eff = self.lam

    @property
    def regressor_bound(self) -> float:
        """Largest allowed ``||X||²``: ``(2 − α)/λ`` (eq. 17); ``inf`` when λ = 0."""
        return math.inf if self.lam == 0.0 else (2.0 - self.alpha) / self.lam

    def predict(self, X: np.ndarray, offset: np.ndarray | float = 0.0) -> np.ndarray:
        """One-step prediction ``Θ̂ X + offset``."""
        return self.theta @ X + offset

    def update(
        self, X: np.ndarray, y_next: np.ndarray, offset: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Apply eq. 16 with the measured ``y_next``; returns the prediction error ỹ."""
        err = y_next - (self.theta @ X + offset)
        lam = self.lam
        self.last_clipped = False
        if lam > 0.0:
            xx = float(X @ X)
            if lam * xx > 2.0 - self.alpha:
                lam = (2.0 - self.alpha) / xx
                self.last_clipped = True
            self.theta += lam * np.outer(err, X)
        self.last_lam_eff = lam
        return err


def excitation_box(
    e: np.ndarray,
    u_center: np.ndarray,
    *,
    lam: float,
    alpha: float,
    bias_regressor: float,
    u_lo: np.ndarray,
    u_hi: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float, bool]:
    r"""First-move box from the excitation bound (002 eq. 26–28).

    :math:`\rho^2 = (2-\alpha)/\lambda - \lVert e\rVert^2 - c_b^2`; the ball
    :math:`\lVert u - u_c\rVert < \rho` is replaced by its inscribed box of half-width
    :math:`\rho/\sqrt m` (eq. 28) and intersected with ``[u_lo, u_hi]`` (force box ∩
    rate window). Where the intersection is empty the bound of ``[u_lo, u_hi]`` closest
    to the box is used for both ends.

    Returns ``(lo, hi, half_width, feasible)``; ``half_width`` is ``inf`` for λ = 0.
    """
    m = u_center.size
    if lam <= 0.0:
        return u_lo.copy(), u_hi.copy(), math.inf, True
    rho2 = (2.0 - alpha) / lam - float(e @ e) - bias_regressor**2
    half = math.sqrt(max(rho2, 0.0) / m)
    lo = np.maximum(u_center - half, u_lo)
    hi = np.minimum(u_center + half, u_hi)
    bad = lo > hi
    feasible = not bool(bad.any()) and rho2 > 0.0
    if bad.any():
        # empty: stick to the reachable bound nearest to the excitation box
        near = np.where(u_center - half > u_hi, u_hi, u_lo)
        lo = np.where(bad, near, lo)
        hi = np.where(bad, near, hi)
    return lo, hi, half, feasible


def feasible_target(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Project per-car inputs onto ``[lo, hi]`` keeping their sum where possible.

    Row-wise water filling (rows of a 2-D ``u`` are stages): inputs beyond a bound are
    clipped and the clipped excess is shared equally by the inputs still inside, until
    nothing is left or every input is at a bound. This is the steady-state target
    calculation of MPC (Muske & Rawlings 1993) reduced to the one equality "same total
    force"; when the total itself is infeasible every input ends at its bound.
    """
    out = np.array(u, dtype=float, copy=True)
    rows = out.reshape(-1, out.shape[-1])
    outside = np.flatnonzero(((rows < lo) | (rows > hi)).any(axis=1))
    for i in outside:
        r = rows[i]  # a view: edited in place
        for _ in range(r.size):
            c = np.clip(r, lo, hi)
            excess = float(np.sum(r - c))
            free = (c > lo) & (c < hi) if excess == 0.0 else (c < hi if excess > 0 else c > lo)
            r[:] = c
            if abs(excess) < 1e-12 or not free.any():
                break
            r[free] += excess / int(free.sum())
        r[:] = np.clip(r, lo, hi)
    return out


def _check_lam(lam: float) -> float:
    x = float(lam)
    if not math.isfinite(x) or x < 0.0:
        raise ValueError(f"lam (adaptation gain λ) must be finite and >= 0, got {lam!r}")
    return x


def _check_alpha(alpha: float) -> float:
    x = float(alpha)
    if not (0.0 < x < 2.0):
        raise ValueError(f"alpha (excitation margin α) must lie in (0, 2), got {alpha!r}")
    return x


# ---------------------------------------------------------------------------------------
# configuration
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AdaptiveMPCConfig:
    """Structural settings of the 002 MPCs (the weights and λ are tunable parameters).

    Attributes:
        Np, Nc: prediction and control horizon (002 Table 1: 10 and 10), 1 <= Nc <= Np <= 50.
        alpha: margin α of the excitation bound (eq. 17), in (0, 2); 002 gives none.
        bias_regressor: constant regressor entry c_b (> 0, <= 100) of the added affine
            column; the offset is learned at rate λ c_b² per step.
        excitation_bound: impose the eq. 26–28 input box (adaptive controller only).
        du_max_kN_per_s: per-car force rate limit [kN/s] in (0, 1e4] (ours; 002 has none).
        r_du: weight on force increments [1/kN²] in [0, 1e3] (ours, small).
        soft_penalty: exact-penalty weight of the soft speed and coupler constraints, > 0.
        relinearise_mps: re-linearise the Davis slope when the reference speed moved
            more than this from the linearisation speed, > 0.
        model_refresh_tol: push the estimated matrices into OSQP when they moved by more
            than this fraction of the nominal ``[A B]`` (RMS over rows of the change
            relative to each nominal row's norm), in [0, 1].
    """

    Np: int = 10
    Nc: int = 10
    alpha: float = 0.5
    bias_regressor: float = 5.0
    excitation_bound: bool = True
    du_max_kN_per_s: float = 20.0
    r_du: float = 1e-2
    soft_penalty: float = 1e3
    relinearise_mps: float = 5.0
    model_refresh_tol: float = 0.02

    def __post_init__(self) -> None:
        for name in ("Np", "Nc"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 1 <= v <= 50:
                raise ValueError(f"{name} must be an integer in [1, 50], got {v!r}")
        if self.Nc > self.Np:
            raise ValueError(f"Nc must lie in [1, Np={self.Np}], got {self.Nc}")
        _check_alpha(self.alpha)
        check_range("bias_regressor", self.bias_regressor, 0.0, 100.0, low_inclusive=False)
        check_range("du_max_kN_per_s", self.du_max_kN_per_s, 0.0, 1e4, low_inclusive=False)
        check_range("r_du", self.r_du, 0.0, 1e3)
        check_range("soft_penalty", self.soft_penalty, 0.0, 1e8, low_inclusive=False)
        check_range("relinearise_mps", self.relinearise_mps, 0.0, 100.0, low_inclusive=False)
        check_range("model_refresh_tol", self.model_refresh_tol, 0.0, 1.0)


# ---------------------------------------------------------------------------------------
# controller
# ---------------------------------------------------------------------------------------
class AdaptiveCruiseMPC(Controller):
    """Paper 002's adaptive MPC for per-car forces (see the module docstring).

    Tunable: ``lam`` (adaptation gain λ, 002: 0.01), ``r_u`` (weight of the force
    deviation from the estimated equilibrium input per kN², 002: R = 0.1), ``q_v``
    (speed weight per (m/s)² and car), ``q_xi`` (coupler deformation weight per mm²).
    Extra constructor keywords are the fields of :class:`AdaptiveMPCConfig`.
    """

    name = "adaptive_mpc"
    adaptive = True
    PARAMS = (
        TunableParam("lam", 0.0, 0.05, 0.01, description="adaptation gain λ (002: 0.01)"),
        TunableParam("r_u", 1e-3, 1e2, 0.1, log=True, description="input weight [1/kN^2]"),
        TunableParam("q_v", 1e-2, 1e3, 1.0, log=True, description="speed weight [s^2/m^2]"),
        TunableParam("q_xi", 1e-3, 1e3, 1.0, log=True, description="coupler weight [1/mm^2]"),
    )

    def __init__(
        self, scenario: Any = None, *, config: AdaptiveMPCConfig | None = None, **kw: Any
    ) -> None:
        fields = set(AdaptiveMPCConfig.__dataclass_fields__)
        cfg_kw = {k: kw.pop(k) for k in list(kw) if k in fields}
        if config is not None and cfg_kw:
            raise ValueError("give either config= or config fields as keywords, not both")
        self.config = config if config is not None else AdaptiveMPCConfig(**cfg_kw)
        self._mpc: LinearMPC | None = None
        self._weights_key: tuple | None = None
        self._est: GradientEstimator | None = None
        del scenario
        super().__init__(**kw)
        self._check_lam_bound(self._params.get("lam", 0.0))

    # ------------------------------------------------------------------ params
    def _lam(self) -> float:
        return float(self._params.get("lam", 0.0)) if self.adaptive else 0.0

    def _check_lam_bound(self, lam: float) -> None:
        cfg = self.config
        lam_max = (2.0 - cfg.alpha) / cfg.bias_regressor**2
        if self.adaptive and lam >= lam_max:
            raise ValueError(
                f"lam must lie in [0, {lam_max:.6g}) so that the bias entry alone keeps "
                f"λ c_b² < 2 − α (c_b = {cfg.bias_regressor}, α = {cfg.alpha}), got {lam}"
            )

    def _on_params_changed(self) -> None:
        self._check_lam_bound(self._params.get("lam", 0.0))
        if self._est is not None:
            lam = self._lam()
            if not math.isclose(lam, self._est.lam, rel_tol=1e-12, abs_tol=0.0):
                self._est.lam = lam
        if self._mpc is not None:
            key = self._wkey()
            old = self._weights_key
            if old is None or any(
                not math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)
                for a, b in zip(key, old, strict=True)
            ):
                with single_thread_blas():
                    Q, R, S = self._weights()
                    # diagonal weights of the checked parameters: no engine checks again
                    self._mpc.replace_weights(Q=Q, R=R, S=S)
                self._weights_key = key

    def _wkey(self) -> tuple[float, float, float]:
        p = self._params
        return (p["r_u"], p["q_v"], p["q_xi"])

    def _weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, n = self._params, self._n
        Q = np.diag(np.r_[np.full(n - 1, p["q_xi"]), np.full(n, p["q_v"]), np.zeros(n)])
        R = self.config.r_du * np.eye(n)
        S = p["r_u"] * np.eye(n)
        return Q, R, S

    # ------------------------------------------------------------------- model
    def _discretise(self, v_lin: float) -> None:
        """Nominal ZOH model in (mm, m/s, kN) with the Davis slope at ``v_lin``."""
        slope = davis_slope(self._cb, self._cc, max(v_lin, 0.0))
        Ac, Bc, Ec = coupled_cars_relative_continuous(self._k, self._damping, self._mi, slope)
        self._Ad, self._Bd, self._Ed = discretise(Ac, Bc, Ec, self.ctx.dt_s)
        self._Bv_inv = np.linalg.inv(self._Bd[self._n - 1 :, :])
        self._slope = slope
        self._v_lin = v_lin

    def _affine_accel(self, s_r: np.ndarray, v_r: np.ndarray) -> np.ndarray:
        """Nominal per-stage, per-car affine accelerations ``(len(v_r), n)`` [m/s²]."""
        w = -resistance_offset_accel(self._ca, self._cb, self._cc, self._slope, self._mi, v_r)
        if self.ctx.track is not None:
            theta = np.asarray(self._grad(s_r), float)[:, None]
            w -= gradient_accel(self._m, self._mi, theta)
        return w

    def _aug(self, A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Model with an input copy appended to the state (for the first-move box)."""
        nx, n = self._nx, self._n
        Aa = np.zeros((nx + n, nx + n))
        Aa[:nx, :nx] = A
        Ba = np.vstack([B, np.eye(n)])
        return Aa, Ba

    def _push_model(self) -> None:
        nx, n = self._nx, self._n
        th = self._est.theta
        dA, dB = th[:, :nx], th[:, nx : nx + n]
        self._mpc.set_model(*self._aug(self._Ad + dA, self._Bd + dB))
        self._dA_p, self._dB_p = dA.copy(), dB.copy()
        self._n_refresh += 1

    # ------------------------------------------------------------------- reset
    def reset(self, ctx: ControlContext) -> None:
        super().reset(ctx)
        cfg = self.config
        tr = ctx.train
        n = ctx.n_cars
        if n < 2 or ctx.n_inputs != n:
            raise ValueError(
                f"{self.name} needs a multi-car train with per-car inputs (n_cars >= 2 and "
                f"n_inputs == n_cars), got n_cars={n}, n_inputs={ctx.n_inputs}"
            )
        self._n, self._nx = n, 2 * n - 1
        self._m, self._mi, self._ca, self._cb, self._cc = per_car_davis(tr)
        self._k = tr.coupler.stiffness_N_per_m
        self._damping = tr.coupler.damping_Ns_per_m
        self._spacing = tr.coupler.rest_length_m
        self._grad = gradient_table(ctx.track) if ctx.track is not None else None
        ex = ctx.extra
        u_bound = float(ex.get("u_bound_car_N", min(ctx.u_max_N[0], -ctx.u_min_N[0]))) / 1e3
        self._u_lo, self._u_hi = np.full(n, -u_bound), np.full(n, u_bound)
        du = cfg.du_max_kN_per_s * ctx.dt_s
        if math.isfinite(ctx.du_max_Nps):
            du = min(du, ctx.du_max_Nps * ctx.dt_s / 1e3)
        self._du = du
        xi_max = float(ex.get("coupler_def_max_m", 0.02)) * 1e3  # mm
        v0 = float(ctx.reference.profile.v_mps[0])
        self._discretise(max(v0, 1.0))

        nx = self._nx
        self._est = GradientEstimator(np.zeros((nx, nx + n + 1)), self._lam(), cfg.alpha)
        self._dA_p = np.zeros((nx, nx))
        self._dB_p = np.zeros((nx, n))
        Q, R, S = self._weights()
        big = 1e6
        # the input-copy rows carry only the first-move excitation box; elsewhere they
        # are inactive (±big: repeating the force box there makes the QP degenerate and
        # slowed OSQP down 3-10x)
        self._ymin0 = np.r_[np.full(n - 1, -xi_max), np.zeros(n), np.full(n, -big)]
        self._ymax0 = np.r_[np.full(n - 1, xi_max), np.full(n, big), np.full(n, big)]
        rho = np.r_[np.full(nx, cfg.soft_penalty), np.full(n, np.inf)]
        Aa, Ba = self._aug(self._Ad, self._Bd)
        self._mpc = LinearMPC(
            Aa,
            Ba,
            None,
            Np=cfg.Np,
            Nc=cfg.Nc,
            Q=Q,
            R=R,
            S=S,
            u_min=self._u_lo,
            u_max=self._u_hi,
            du_min=np.full(n, -du),
            du_max=np.full(n, du),
            y_min=self._ymin0,
            y_max=self._ymax0,
            soft_penalty={"y": rho},
        )
        self._weights_key = self._wkey()
        Np = cfg.Np
        self._yref = np.zeros((Np, nx + n))
        self._ymin = np.tile(self._ymin0, (Np, 1))
        self._ymax = np.tile(self._ymax0, (Np, 1))
        self._D = np.zeros((Np, nx + n))
        self._prev: tuple[np.ndarray, np.ndarray] | None = None
        self._n_refresh = 0

    # ----------------------------------------------------------------- helpers
    def _relative_change(self, dA: np.ndarray, dB: np.ndarray) -> float:
        """RMS over rows of the unpushed change of [ΔA ΔB], relative to the nominal rows."""
        rows = np.linalg.norm(np.hstack([self._Ad, self._Bd]), axis=1)
        ch = np.linalg.norm(np.hstack([dA - self._dA_p, dB - self._dB_p]), axis=1)
        return float(np.sqrt(np.mean((ch / rows) ** 2)))

    def _state(self, obs: Observation) -> np.ndarray:
        n = self._n
        q = np.asarray(obs.positions_m, float) + np.arange(n) * self._spacing
        xi = (q[:-1] - q[1:]) * 1e3  # mm, tension > 0
        return np.concatenate([xi, np.asarray(obs.speeds_mps, float)])

    def estimated_resistance_deviation_kN(self) -> np.ndarray:
        """Per-car running-resistance deviation implied by the learned bias [kN]."""
        n, nx = self._n, self._nx
        b = self.config.bias_regressor * self._est.theta[n - 1 : nx, -1]
        return -(self._Bv_inv @ b)

    # ----------------------------------------------------------------- control
    def compute(self, obs: Observation) -> tuple[np.ndarray, Mapping[str, Any]]:
        ctx, cfg, est = self.ctx, self.config, self._est
        n, nx, Np = self._n, self._nx, cfg.Np
        cb = cfg.bias_regressor
        x = self._state(obs)
        u_prev = np.asarray(obs.u_prev_N, float) / 1e3

        # ---- adaptive law (eq. 16) with the regressor of the previous step -----------
        est_err = math.nan
        est_err_v = math.nan
        if self._prev is not None:
            X_prev, x_nom = self._prev
            err = est.update(X_prev, x, offset=x_nom)
            est_err = float(np.linalg.norm(err))
            est_err_v = float(np.linalg.norm(err[n - 1 :]))

        # ---- reference and nominal model along the horizon ----------------------------
        ts = obs.t_s + ctx.dt_s * np.arange(Np + 1)
        prof = ctx.reference.profile
        s_r = np.asarray(prof.s_at_t(ts), float)
        v_r = np.asarray(prof.v_at_t(ts), float)
        relin = abs(float(v_r[0]) - self._v_lin) > cfg.relinearise_mps
        if relin:
            self._discretise(max(float(v_r[0]), 0.0))
        th = est.theta
        dA, dB = th[:, :nx], th[:, nx : nx + n]
        refreshed = False
        if relin or (est.lam > 0.0 and self._relative_change(dA, dB) > cfg.model_refresh_tol):
            self._push_model()
            refreshed = True
        Ad, Bd, Ed = self._Ad, self._Bd, self._Ed
        d_nom = self._affine_accel(s_r[:Np], v_r[:Np]) @ Ed.T  # (Np, nx)
        bias = cb * th[:, -1]
        Xr = np.zeros((Np + 1, nx))
        Xr[:, n - 1 :] = v_r[:, None]
        # estimated equilibrium input along the reference (velocity rows, eq. 4 + a_r)
        rhs = Xr[1:, n - 1 :] - Xr[:-1] @ Ad[n - 1 :, :].T - d_nom[:, n - 1 :] - bias[n - 1 :]
        u_ff = rhs @ self._Bv_inv.T  # (Np, n)

        # target inputs for the r_u term: the equilibrium input made feasible (a saturated
        # car's excess is shared by the others, so the cost never pulls the free cars
        # away from the force the train needs)
        u_tgt = feasible_target(u_ff, self._u_lo, self._u_hi)

        # ---- MPC data --------------------------------------------------------------
        D = self._D
        D[:, :nx] = d_nom + bias - Xr[:-1] @ self._dA_p.T - u_ff @ self._dB_p.T
        yref = self._yref
        yref[:, n - 1 : nx] = v_r[1:, None]
        ymin, ymax = self._ymin, self._ymax
        if ctx.track is not None:
            ymax[:, n - 1 : nx] = np.asarray(ctx.track.speed_limit_at(s_r[1:]), float)[:, None]
        # excitation bound → first-move box (eq. 26–28), inside force box ∩ rate window
        e = x - Xr[0]
        w_lo = np.maximum(self._u_lo, u_prev - self._du)
        w_hi = np.minimum(self._u_hi, u_prev + self._du)
        w_lo, w_hi = np.minimum(w_lo, w_hi), np.maximum(w_lo, w_hi)
        use_box = self.adaptive and cfg.excitation_bound and est.lam > 0.0
        lo, hi, half, feasible = excitation_box(
            e,
            u_ff[0],
            lam=est.lam if use_box else 0.0,
            alpha=cfg.alpha,
            bias_regressor=cb,
            u_lo=w_lo,
            u_hi=w_hi,
        )
        if use_box:
            ymin[0, nx:] = lo
            ymax[0, nx:] = hi
        x_aug = np.concatenate([x, u_prev])
        sol = self._mpc.solve(x_aug, u_prev, yref, d=D, u_ref=u_tgt, y_min=ymin, y_max=ymax)
        u0 = sol.u0.copy()
        if use_box:  # remove the solver's O(eps) violation of the hard first-move box
            u0 = np.clip(u0, lo, hi)

        # ---- regressor and nominal prediction for the next update ---------------------
        X = np.concatenate([e, u0 - u_ff[0], [cb]])
        x_nom = Ad @ x + Bd @ u0 + d_nom[0]
        self._prev = (X, x_nom)

        info = sol.solver_info()
        dR = self.estimated_resistance_deviation_kN()
        info.update(
            est_error=est_err,
            est_error_v=est_err_v,
            theta_norm=float(np.linalg.norm(th)),
            dR_hat_kN=dR,
            dR_hat_total_kN=float(dR.sum()),
            excitation_half_width_kN=half,
            excitation_feasible=feasible,
            regressor_norm2=float(X @ X),
            lam_eff=est.last_lam_eff,
            bound_clipped=est.last_clipped,
            model_refreshed=refreshed,
            u_ff_kN=u_ff[0].copy(),
        )
        return u0 * 1e3, info


class NominalCruiseMPC(AdaptiveCruiseMPC):
    """Paper 002's non-adaptive comparator: the same MPC on the nominal model.

    The estimate is frozen at zero correction (λ = 0, so no excitation box): the
    prediction uses the nominal Davis coefficients c0*, c1*, c2* while the plant's vary.
    No observer or integral action (none in 002's comparator either).
    """

    name = "mpc002"
    adaptive = False
    PARAMS = tuple(p for p in AdaptiveCruiseMPC.PARAMS if p.name != "lam")
