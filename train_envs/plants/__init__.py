"""Train plants: single-point (paper 001) and multi-car cascade (papers 000, 002, 003)."""

from train_envs.plants.multi_car import ActuatorParams, TrainPlant
from train_envs.plants.point_mass import PointMassTrain
from train_envs.plants.resistance import (
    BoundedRandomDisturbance,
    ConstantWind,
    DavisVariation,
    Disturbance,
    HarmonicWind,
)

__all__ = [
    "ActuatorParams",
    "BoundedRandomDisturbance",
    "ConstantWind",
    "DavisVariation",
    "Disturbance",
    "HarmonicWind",
    "PointMassTrain",
    "TrainPlant",
]
