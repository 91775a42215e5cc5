"""Fixtures shared by the whole suite.

The suite is laid out by package (``tests/plants``, ``lines``, ``mpc``, ``controllers``,
``simulation``, ``envs``, ``tuners``, ``agents``, ``cli``); the cross-cutting checks
(goldens, layering, compiled twins, notebooks) sit at the top. This file's folder is on
``sys.path``, so every test can import :mod:`golden.cases`.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def paper001():
    """Paper 001's stopping scenario (490 t HST, lag + dead time)."""
    from train_envs.scenarios import get_scenario

    return get_scenario("paper001_stopping")


@pytest.fixture(scope="session")
def paper003():
    """Paper 003's cruise (8 cars, second-order actuators)."""
    from train_envs.scenarios import get_scenario

    return get_scenario("paper003_cruise")
