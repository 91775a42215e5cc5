"""Paper 003: fuzzy constrained predictive cruise control with a backstepping compensator.

Most of paper 003's formulas were lost in extraction; what is implemented is the
standard form of each building block, with the source named in each module:

* :mod:`.memberships` — triangular memberships of the lead car's speed error, the
  premise of the T-S fuzzy model (003 §2.2; Tanaka & Wang 2001);
* :mod:`.model` — the error model about the cruise equilibrium (003 §2.1) and its scaled
  modal reduction, the design model of every rule;
* :mod:`.lmi` — the per-step min-γ LMI with PDC gains (003 Theorem 3; Kothare,
  Balakrishnan & Morari 1996), cvxpy + Clarabel;
* :mod:`.compensator` — the backstepping compensator of the second-order actuator
  (003 Theorem 5; Krstić et al. 1995);
* :mod:`.controller` — :class:`FuzzyMPCController` (``"fuzzy_mpc"``): the control step
  and the policy that decides when the LMI is re-solved.

Design notes and measurements: ``docs/design/fuzzy_mpc.md``.
"""

from __future__ import annotations

from train_envs.controllers.fuzzy_mpc.compensator import BacksteppingCompensator
from train_envs.controllers.fuzzy_mpc.controller import FuzzyMPCController
from train_envs.controllers.fuzzy_mpc.lmi import KothareLMI, LMISolution, _sqrt_factor  # noqa: F401
from train_envs.controllers.fuzzy_mpc.memberships import TriangularMemberships
from train_envs.controllers.fuzzy_mpc.model import ReducedTrainModel

__all__ = [
    "BacksteppingCompensator",
    "FuzzyMPCController",
    "KothareLMI",
    "LMISolution",
    "ReducedTrainModel",
    "TriangularMemberships",
]
