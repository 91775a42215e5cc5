"""What a controller needs of a scenario, and the refusal of an unsupported one.

:func:`unsupported_reason` answers whether a controller can run a scenario: ``None``
when it can, else the one-line reason: the message of the ``ValueError`` that its
construction on the scenario, or its reset to the scenario's control context, raises
(it names the requirement, e.g. a multi-car train with per-car inputs).
:class:`UnsupportedScenarioError` is the error of such a refusal.
"""

from __future__ import annotations

from typing import Any

__all__ = ["UnsupportedScenarioError", "unsupported_reason"]


class UnsupportedScenarioError(ValueError):
    """A controller refuses a scenario it cannot run; the message names the requirement."""


def unsupported_reason(controller: str, scenario: Any) -> str | None:
    """``None`` if controller ``controller`` (a name) can run ``scenario`` (a
    :class:`train_envs.scenarios.Scenario`, a layer above: not imported), else the reason
    in one line. An unknown controller name raises the ``ValueError`` of
    :func:`~train_envs.controllers.make_controller`."""
    from train_envs.controllers import list_controllers, make_controller
    from train_envs.validation import check_choice

    check_choice("controller", controller, list_controllers())
    try:
        make_controller(controller, scenario).reset(scenario.control_context())
    except ValueError as exc:
        return " ".join(str(exc).split()) or type(exc).__name__
    return None
