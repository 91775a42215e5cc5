r"""Dynamic matrix control with online softening and correction adjustment (paper 004).

Paper 004 (MPC-MOWOA) tracks the speed profile with a dynamic matrix controller (DMC)
whose reference-softening factor α and feedback-correction coefficient h_c are adjusted
online by fuzzy logic; the seven parameters of that adjustment are what its MOWOA tunes
(004 §3.4). The formulas of 004 §4 were lost in extraction; the standard DMC forms are
used and cited in the modules (Cutler & Ramaker, "Dynamic matrix control — a computer
control algorithm", *Joint Automatic Control Conf.*, 1980; Xi Yugeng, *Predictive
Control*, 2nd ed., 2013, ch. 2; Camacho & Bordons, *Model Predictive Control*, 2nd ed.,
2007, ch. 3). Signs: e = y_r − v (tracking error, y_r the DMC's setpoint), ė its rate.

Sections of 004 §4 and where they live:

1. step-response model, integrating tail, dynamic matrix, classic gain (004 §4.1):
   :mod:`.step_response`;
2. reference trajectory (setpoint preview, softened reference) and rolling
   optimisation (004 §4.2): :mod:`.setpoint`, :mod:`.laws`, :mod:`.qp`;
3. feedback correction and shift of the prediction vector (004 §4.3): :mod:`.prediction`;
4. online softening factor from the fuzzy satisfaction index (004 §4.4): :mod:`.laws`;
5. online correction coefficient from the rule base :data:`H_TABLE` (004 §4.5):
   :mod:`.laws`;
6. command: feedforward, comfort jerk, envelope, rate limit and split:
   :mod:`.laws`, :mod:`.controller`.

:class:`DMCController` (:mod:`.controller`) runs one step from these laws — they are
the only implementations. The choices made where 004 is silent, the tuning of the
defaults and the measurements behind them are in ``docs/design/dmc.md``.
"""

from train_envs.controllers.dmc.controller import KMH, DMCController
from train_envs.controllers.dmc.laws import (
    H_TABLE,
    SatisfactionShape,
    correction_coefficient,
    correction_rules,
    feedforward_force,
    filtered_rate,
    output_satisfaction,
    position_catchup,
    response_time,
    satisfaction,
    softened_reference,
    softened_reference_error,
    softening_factor,
    softening_weights,
    time_satisfaction,
    with_catchup,
)
from train_envs.controllers.dmc.prediction import (
    add_move,
    correct_and_shift,
    extrapolate_tail,
    predict,
    shift_prediction,
)
from train_envs.controllers.dmc.qp import DMCProblem
from train_envs.controllers.dmc.setpoint import SetpointPreview
from train_envs.controllers.dmc.step_response import (
    dmc_gain,
    dynamic_matrix,
    extend_step_response,
    step_response,
    tail_ratio,
)

__all__ = [
    "DMCController",
    "DMCProblem",
    "H_TABLE",
    "KMH",
    "SatisfactionShape",
    "SetpointPreview",
    "add_move",
    "correct_and_shift",
    "correction_coefficient",
    "correction_rules",
    "dmc_gain",
    "dynamic_matrix",
    "extend_step_response",
    "extrapolate_tail",
    "feedforward_force",
    "filtered_rate",
    "output_satisfaction",
    "position_catchup",
    "predict",
    "response_time",
    "satisfaction",
    "shift_prediction",
    "softened_reference",
    "softened_reference_error",
    "softening_factor",
    "softening_weights",
    "step_response",
    "tail_ratio",
    "time_satisfaction",
    "with_catchup",
]
