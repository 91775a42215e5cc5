"""Fixtures of the tuner tests."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _quiet_optuna():
    """Optuna's per-trial INFO lines off (warnings still show)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
