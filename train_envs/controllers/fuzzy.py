"""Small, fast fuzzy-logic machinery shared by the fuzzy controllers.

Used by the Fuzzy-PID baseline (gain scheduling on error and error rate), the AFSMC's
adaptive fuzzy approximator and, later, the DMC's online softening-factor and
correction-coefficient adjustment (paper 004).

Conventions (chosen here; the papers do not give them)
-----------------------------------------------------
* **Universe of discourse** [−3, 3] with the seven standard linguistic terms
  NB, NM, NS, ZO, PS, PM, PB centred at −3, −2, …, 3 — the discrete universe
  {−3, …, 3} of the classic self-tuning Fuzzy-PID literature. A physical input x is
  mapped onto it by a **quantisation factor** k: ``x_q = sat(k x, −3, 3)`` (inputs
  beyond the universe belong fully to NB or PB).
* **Membership functions**: a *strong triangular partition* — triangles between
  neighbouring centres, with the outer terms NB/PB as shoulders (trapezoids open to
  ±∞). Every x belongs to at most two neighbouring terms and the memberships sum to one
  (Passino & Yurkovich, *Fuzzy Control*, 1998, ch. 2).
  :func:`trimf`, :func:`trapmf` and :func:`gaussmf` are provided for other shapes.
* **Rule base**: two-input Mamdani-type rules "IF e is A_i AND ec is B_j THEN y is
  C_{T[i, j]}" given as a 7 × 7 table ``T`` of output term indices (0 = NB … 6 = PB)
  (Mamdani & Assilian, "An experiment in linguistic synthesis with a fuzzy logic
  controller", *Int. J. Man-Machine Studies* 7(1), 1975). Several tables sharing
  the same inputs (e.g. ΔK_p, ΔK_i, ΔK_d) can be evaluated at once.
* **Inference and defuzzification**: the premise "AND" is the product (default) or the
  minimum; the output is the centre-of-sets / centre-average defuzzification
  ``y = Σ_ij w_ij c_{T[i,j]} / Σ_ij w_ij`` with ``w_ij = μ_i(e) ⋆ μ_j(ec)`` and ``c_k``
  the centres of the output terms (Passino & Yurkovich 1998, ch. 2; Wang L.-X.,
  *Adaptive Fuzzy Systems and Control*, 1994). With product inference on strong
  triangular partitions Σ w = 1 and the controller is exactly the bilinear
  interpolation of the consequent table between the term centres — continuous,
  bounded by the consequent range, and monotone wherever the table is.

Speed: a strong partition activates at most 2 × 2 = 4 rules, so the scalar path
(:meth:`RuleBase2.__call__`) locates the active cell in O(1) and evaluates only those
four rules (a few microseconds); :meth:`RuleBase2.evaluate` is the vectorised batch
path over many inputs, built from outer products of the two membership vectors.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence

import numpy as np

from train_envs.validation import check_finite

#: the seven standard linguistic terms, in order
TERMS: tuple[str, ...] = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
#: term indices, for writing rule tables readably
NB, NM, NS, ZO, PS, PM, PB = range(7)
#: half-width of the normalised universe [−UNIVERSE, UNIVERSE]
UNIVERSE = 3.0


def _finite(name: str, x: float) -> float:
    return check_finite(f"fuzzy input {name}", x)


def _finite_array(name: str, x: np.ndarray | Sequence[float] | float) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"fuzzy input {name} must be finite (found NaN or inf)")
    return a


# ------------------------------------------------------------------ membership shapes
def trimf(x: np.ndarray | float, a: float, b: float, c: float) -> np.ndarray:
    """Triangular membership: 0 at ``a`` and ``c``, 1 at ``b`` (a ≤ b ≤ c).

    ``a == b`` or ``b == c`` give a vertical left/right edge (a half-triangle).
    """
    if not a <= b <= c:
        raise ValueError(f"trimf needs a <= b <= c, got {a}, {b}, {c}")
    return trapmf(x, a, b, b, c)


def trapmf(x: np.ndarray | float, a: float, b: float, c: float, d: float) -> np.ndarray:
    """Trapezoidal membership: rises on [a, b], 1 on [b, c], falls on [c, d].

    Use ``a = b = -inf`` or ``c = d = inf`` for shoulders open to one side.
    """
    if not a <= b <= c <= d:
        raise ValueError(f"trapmf needs a <= b <= c <= d, got {a}, {b}, {c}, {d}")
    if type(x) is float or type(x) is int:  # scalar fast path, same value (np.float64)
        return np.float64(trapmf_scalar(x, a, b, c, d))
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        up = np.where(x >= b, 1.0, (x - a) / (b - a)) if b > a else np.where(x >= b, 1.0, 0.0)
        down = np.where(x <= c, 1.0, (d - x) / (d - c)) if d > c else np.where(x <= c, 1.0, 0.0)
    # np.maximum/np.minimum: the same result as np.clip (NaN propagates), ~10x less overhead
    return np.maximum(np.minimum(np.minimum(up, down), 1.0), 0.0)


def trapmf_scalar(x: float, a: float, b: float, c: float, d: float) -> float:
    """:func:`trapmf` of one number as a Python float (same arithmetic, no validation).

    For hot loops with precomputed, already checked corners ``a <= b <= c <= d``.
    """
    x = float(x)
    if x >= b:
        up = 1.0
    elif b > a:
        up = (x - a) / (b - a)  # nan for a NaN x or inf - inf, as in the array path
    else:
        up = 0.0
    if x <= c:
        down = 1.0
    elif d > c:
        down = (d - x) / (d - c)
    else:
        down = 0.0
    if up != up or down != down:
        return math.nan
    m = up if up < down else down
    return 1.0 if m > 1.0 else (0.0 if m < 0.0 else m)


def gaussmf(x: np.ndarray | float, c: float, sigma: float) -> np.ndarray:
    """Gaussian membership ``exp(−(x − c)² / (2 σ²))``."""
    if not sigma > 0:
        raise ValueError(f"gaussmf needs sigma > 0, got {sigma}")
    x = np.asarray(x, dtype=float)
    return np.exp(-0.5 * ((x - c) / sigma) ** 2)


# ------------------------------------------------------------------ partitions
class TriangularPartition:
    """Strong triangular partition over increasing term centres (outer terms are shoulders).

    ``μ_k(x)`` is the triangle (c_{k−1}, c_k, c_{k+1}); the first and last terms stay 1
    beyond the outermost centres. For any x at most two neighbouring memberships are
    non-zero and they sum to one.
    """

    def __init__(self, centres: Sequence[float] | np.ndarray) -> None:
        c = np.asarray(centres, dtype=float).reshape(-1)
        if c.size < 2:
            raise ValueError(f"a partition needs at least 2 centres, got {c.size}")
        if not np.all(np.isfinite(c)) or np.any(np.diff(c) <= 0):
            raise ValueError(f"partition centres must be finite and strictly increasing, got {c}")
        self.centres = c
        self.n = int(c.size)
        self._lo = float(c[0])
        self._hi = float(c[-1])
        steps = np.diff(c)
        self._uniform = bool(np.allclose(steps, steps[0], rtol=1e-12, atol=0.0))
        self._h = float(steps[0])
        self._clist = [float(v) for v in c]

    def locate(self, x: float) -> tuple[int, float]:
        """Active cell of scalar ``x``: index i of the left term and μ_{i+1}(x).

        μ_i(x) = 1 − w, μ_{i+1}(x) = w, every other membership is 0.
        """
        if x <= self._lo:
            return 0, 0.0
        if x >= self._hi:
            return self.n - 2, 1.0
        if self._uniform:
            f = (x - self._lo) / self._h
            i = min(int(f), self.n - 2)
            return i, min(1.0, f - i)
        i = bisect.bisect_right(self._clist, x) - 1
        i = min(max(i, 0), self.n - 2)
        c0, c1 = self._clist[i], self._clist[i + 1]
        return i, (x - c0) / (c1 - c0)

    def memberships(self, x: np.ndarray | float) -> np.ndarray:
        """Membership of every term, shape ``x.shape + (n,)`` (vectorised)."""
        x = np.asarray(x, dtype=float)
        xc = np.clip(x, self._lo, self._hi)
        i = np.clip(np.searchsorted(self.centres, xc, side="right") - 1, 0, self.n - 2)
        w = (xc - self.centres[i]) / (self.centres[i + 1] - self.centres[i])
        out = np.zeros(x.shape + (self.n,))
        np.put_along_axis(out, i[..., None], (1.0 - w)[..., None], axis=-1)
        np.put_along_axis(out, (i + 1)[..., None], w[..., None], axis=-1)
        return out


def standard_partition(universe: float = UNIVERSE) -> TriangularPartition:
    """The seven-term partition NB…PB with centres evenly spread over [−universe, universe]."""
    if not universe > 0:
        raise ValueError(f"universe must be > 0, got {universe}")
    return TriangularPartition(np.linspace(-universe, universe, len(TERMS)))


def quantise(x: float, k: float, universe: float = UNIVERSE) -> float:
    """Map a physical value onto the universe: ``sat(k x, −universe, universe)``."""
    v = k * x
    return -universe if v < -universe else (universe if v > universe else v)


def term_index(name: str) -> int:
    """Index of a linguistic term name (``"NB"`` → 0 … ``"PB"`` → 6)."""
    try:
        return TERMS.index(name.upper())
    except ValueError as exc:
        raise ValueError(f"unknown fuzzy term {name!r}; choose one of: {', '.join(TERMS)}") from exc


def _check_table(table: np.ndarray | Sequence, shape: tuple[int, ...], n_out: int) -> np.ndarray:
    t = np.asarray(table)
    if t.shape[-len(shape):] != shape or t.ndim not in (len(shape), len(shape) + 1):
        raise ValueError(f"rule table must have shape {shape} or (m, *{shape}), got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        if not np.all(np.isfinite(t.astype(float))) or np.any(t != np.round(t)):
            raise ValueError("rule table entries must be integer term indices")
        t = t.astype(int)
    if np.any(t < 0) or np.any(t >= n_out):
        raise ValueError(f"rule table entries must be term indices in [0, {n_out - 1}]")
    return t


# ------------------------------------------------------------------ rule bases
class RuleBase2:
    """Two-input Mamdani rule base with product/min inference and centre-of-sets output.

    Args:
        table: output term indices, shape (n_e, n_ec) or (m, n_e, n_ec) for m outputs
            sharing the same inputs.
        partition_e, partition_ec: input partitions (default: the standard 7 terms).
        consequents: centres of the output terms (default −3 … 3).
        inference: ``"product"`` (default) or ``"min"`` for the premise AND.
        scale_e, scale_ec: quantisation factors applied to the raw inputs
            (``e_q = sat(scale_e · e)``); may be changed at any time.
        names: input names used in error messages.

    Call with scalars for one evaluation (returns a float, or an array of m values);
    :meth:`evaluate` takes arrays.
    """

    def __init__(
        self,
        table: np.ndarray | Sequence,
        partition_e: TriangularPartition | None = None,
        partition_ec: TriangularPartition | None = None,
        consequents: Sequence[float] | np.ndarray | None = None,
        *,
        inference: str = "product",
        scale_e: float = 1.0,
        scale_ec: float = 1.0,
        names: tuple[str, str] = ("e", "ec"),
    ) -> None:
        if inference not in ("product", "min"):
            raise ValueError(f"inference must be 'product' or 'min', got {inference!r}")
        self.pe = partition_e or standard_partition()
        self.pc = partition_ec or standard_partition()
        cons = np.linspace(-UNIVERSE, UNIVERSE, len(TERMS)) if consequents is None else consequents
        self.consequents = np.asarray(cons, dtype=float).reshape(-1)
        if not np.all(np.isfinite(self.consequents)):
            raise ValueError("consequent centres must be finite")
        t = _check_table(table, (self.pe.n, self.pc.n), self.consequents.size)
        self.single = t.ndim == 2
        self.table = t if not self.single else t[None]
        #: consequent centre of every rule, shape (m, n_e, n_ec)
        self.C = self.consequents[self.table]
        self.m = self.C.shape[0]
        self._Cl = self.C.tolist()  # nested lists: the scalar path runs on Python floats
        self.inference = inference
        self.scale_e = float(scale_e)
        self.scale_ec = float(scale_ec)
        self.names = names

    @property
    def output_range(self) -> tuple[float, float]:
        return float(self.consequents.min()), float(self.consequents.max())

    def __call__(self, e: float, ec: float) -> float | np.ndarray:
        """Scalar evaluation (four active rules only)."""
        out = self.outputs(e, ec)
        return out[0] if self.single else np.array(out)

    def outputs(self, e: float, ec: float) -> list[float]:
        """Scalar evaluation as a list of the m outputs (Python floats; no array built).

        The same arithmetic as :meth:`__call__`, for per-step loops that consume the
        outputs as scalars.
        """
        # finite Python floats skip the validating conversion (x - x is 0 iff x is finite)
        if type(e) is not float or e - e != 0.0:
            e = _finite(self.names[0], e)
        if type(ec) is not float or ec - ec != 0.0:
            ec = _finite(self.names[1], ec)
        e *= self.scale_e
        ec *= self.scale_ec
        i, a = self.pe.locate(e)
        j, b = self.pc.locate(ec)
        j1 = j + 1
        if self.inference == "product":
            a1, b1 = 1.0 - a, 1.0 - b
            w00, w01, w10, w11 = a1 * b1, a1 * b, a * b1, a * b
            # centre of sets with Σw = 1: the division by the norm (1.0) is exact, omitted
            i1 = i + 1
            out = []
            for c in self._Cl:
                r0, r1 = c[i], c[i1]
                out.append(w00 * r0[j] + w01 * r0[j1] + w10 * r1[j] + w11 * r1[j1])
            return out
        w00, w01 = min(1.0 - a, 1.0 - b), min(1.0 - a, b)
        w10, w11 = min(a, 1.0 - b), min(a, b)
        norm = w00 + w01 + w10 + w11
        return [
            (w00 * c[i][j] + w01 * c[i][j1] + w10 * c[i + 1][j] + w11 * c[i + 1][j1]) / norm
            for c in self._Cl
        ]

    def firing_strengths(self, e: np.ndarray | float, ec: np.ndarray | float) -> np.ndarray:
        """Rule weights w_ij = μ_i(e) ⋆ μ_j(ec), shape ``e.shape + (n_e, n_ec)``."""
        e = _finite_array(self.names[0], e) * self.scale_e
        ec = _finite_array(self.names[1], ec) * self.scale_ec
        me = self.pe.memberships(e)
        mc = self.pc.memberships(ec)
        if self.inference == "product":
            return me[..., :, None] * mc[..., None, :]
        return np.minimum(me[..., :, None], mc[..., None, :])

    def evaluate(self, e: np.ndarray | float, ec: np.ndarray | float) -> np.ndarray:
        """Vectorised evaluation: shape ``broadcast(e, ec).shape`` (+ ``(m,)`` if several)."""
        e, ec = np.broadcast_arrays(np.asarray(e, float), np.asarray(ec, float))
        w = self.firing_strengths(e, ec)
        num = np.einsum("...ij,mij->...m", w, self.C)
        y = num / w.sum(axis=(-2, -1))[..., None]
        return y[..., 0] if self.single else y


class RuleBase1:
    """Single-input rule base "IF x is A_i THEN y is C_{T[i]}" (centre-of-sets output).

    With a strong partition this is the piecewise-linear interpolation of the
    consequents between the term centres. ``table`` has shape (n,) or (m, n).
    """

    def __init__(
        self,
        table: np.ndarray | Sequence,
        partition: TriangularPartition | None = None,
        consequents: Sequence[float] | np.ndarray | None = None,
        *,
        scale: float = 1.0,
        name: str = "x",
    ) -> None:
        self.p = partition or standard_partition()
        cons = np.linspace(-UNIVERSE, UNIVERSE, len(TERMS)) if consequents is None else consequents
        self.consequents = np.asarray(cons, dtype=float).reshape(-1)
        if not np.all(np.isfinite(self.consequents)):
            raise ValueError("consequent centres must be finite")
        t = _check_table(table, (self.p.n,), self.consequents.size)
        self.single = t.ndim == 1
        self.table = t if not self.single else t[None]
        self.C = self.consequents[self.table]
        self.m = self.C.shape[0]
        self._Cl = self.C.tolist()
        self.scale = float(scale)
        self.name = name

    def __call__(self, x: float) -> float | np.ndarray:
        x = _finite(self.name, x) * self.scale
        i, a = self.p.locate(x)
        out = [(1.0 - a) * c[i] + a * c[i + 1] for c in self._Cl]
        return out[0] if self.single else np.array(out)

    def evaluate(self, x: np.ndarray | float) -> np.ndarray:
        mu = self.p.memberships(_finite_array(self.name, x) * self.scale)
        y = np.einsum("...i,mi->...m", mu, self.C) / mu.sum(axis=-1)[..., None]
        return y[..., 0] if self.single else y
