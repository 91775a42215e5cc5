"""Train plants: single-point (paper 001) and multi-car cascade (papers 000, 002, 003).

The names below load on first access, so that :mod:`train_envs.trains` can use
:mod:`train_envs.plants.physics` without importing the plants that use the trains.
"""

from __future__ import annotations

from train_envs._lazy import lazy_exports

_HOMES = {
    "ActuatorParams": "train_envs.plants.actuator",
    "TrainPlant": "train_envs.plants.multi_car",
    "PointMassTrain": "train_envs.plants.point_mass",
    "BoundedRandomDisturbance": "train_envs.plants.resistance",
    "ConstantWind": "train_envs.plants.resistance",
    "DavisVariation": "train_envs.plants.resistance",
    "Disturbance": "train_envs.plants.resistance",
    "HarmonicWind": "train_envs.plants.resistance",
}

__all__ = sorted(_HOMES)
__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
