"""Structural (non-tunable) options of paper 001's tube and self-triggered MPCs."""

from __future__ import annotations

from dataclasses import dataclass

from train_envs.validation import check_range

__all__ = ["DEFAULT_W_BOUND_MPS2", "TubeSettings"]

#: default bound of the unknown resistance [m/s²] (about paper 001's basic resistance at
#: 20 m/s, 6.25 N/kN = 0.061 m/s², and the library's usual random disturbance)
DEFAULT_W_BOUND_MPS2 = 0.05


@dataclass(frozen=True)
class TubeSettings:
    """Structural (non-tunable) options of the robust MPCs; validated on construction.

    Attributes:
        N: prediction horizon (001: 3 … 15).
        w_bound_mps2: bound w̄ of the unknown resistance per unit mass before ``w_scale``.
        feedback_weights: (q_s, q_v, r) of the LQR tube feedback, or ``"cost"`` for the
            cost weights (K and P then from one Riccati equation).
        jerk_max: command rate limit [m/s³] (``|Δu| ≤ jerk_max T``).
        soft_penalty: exact L1 penalty of the soft stage rows (s, v, command).
        terminal_steps: LQR-law steps ``t`` at which the (hard) terminal set checks the
            rows; ``()`` = no terminal set.
        tighten: False gives the nominal MPC (same QP, no tightening).
        feas_tol: largest slack [m, m/s, m/s²] still counted as feasible (RSMPC).
        overrun_allowance_m: the position row is ``s ≤ s_stop + allowance``; ``None`` =
            the scenario's stopping window (``extra["stop_window_m"]``, else 0.5 m).
        v_min_row: add the soft row ``v ≥ 0`` (off by default: near standstill the linear
            prediction crosses zero speed; ``docs/design/tube_mpc.md``).
        terminal_speed_rows: the terminal set also checks ``v ≤ v_limit``.
        command_box: ``"soft"``, ``"hard"`` or ``"off"``: the tightened command box.
    """

    N: int = 10
    w_bound_mps2: float = DEFAULT_W_BOUND_MPS2
    feedback_weights: tuple[float, float, float] | str = (10.0, 30.0, 10.0)
    jerk_max: float = 1.0
    soft_penalty: float = 1e3
    terminal_steps: tuple[int, ...] = (2, 5, 10, 20, 40)
    tighten: bool = True
    feas_tol: float = 1e-3
    overrun_allowance_m: float | None = None
    v_min_row: bool = False
    terminal_speed_rows: bool = True
    command_box: str = "soft"

    def __post_init__(self) -> None:
        if isinstance(self.N, bool) or int(self.N) != self.N or not 1 <= self.N <= 60:
            raise ValueError(f"N must be an integer in [1, 60], got {self.N!r}")
        check_range("w_bound_mps2", self.w_bound_mps2, 0.0, 1.0)
        fw = self.feedback_weights
        if isinstance(fw, str):
            if fw != "cost":
                raise ValueError(f"feedback_weights must be 'cost' or (q_s, q_v, r), got {fw!r}")
        else:
            if len(fw) != 3:
                raise ValueError(f"feedback_weights must be (q_s, q_v, r), got {fw!r}")
            for name, val in zip(("q_s", "q_v", "r"), fw, strict=True):
                check_range(f"feedback_weights {name}", val, 0.0, 1e8, low_inclusive=False)
        check_range("jerk_max", self.jerk_max, 0.0, 100.0, low_inclusive=False)
        check_range("soft_penalty", self.soft_penalty, 0.0, 1e8, low_inclusive=False)
        ts = tuple(self.terminal_steps)
        if any(isinstance(t, bool) or int(t) != t or not 1 <= t <= 500 for t in ts):
            raise ValueError(f"terminal_steps must be integers in [1, 500], got {ts!r}")
        if len(set(ts)) != len(ts):
            raise ValueError(f"terminal_steps must not repeat, got {ts!r}")
        check_range("feas_tol", self.feas_tol, 0.0, 1.0, low_inclusive=False)
        if self.command_box not in ("soft", "hard", "off"):
            raise ValueError(
                f"command_box must be 'soft', 'hard' or 'off', got {self.command_box!r}"
            )
        if self.overrun_allowance_m is not None:
            check_range("overrun_allowance_m", self.overrun_allowance_m, 0.0, 100.0)
