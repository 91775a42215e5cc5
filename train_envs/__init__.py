"""train-envs: Gymnasium environments for automatic train operation (ATO).

Importing the package registers the env ids (namespace ``TrainEnvs``) with Gymnasium;
registration is idempotent.
"""

from train_envs.envs.registration import register_envs

__version__ = "0.1.0"

register_envs()

__all__ = ["__version__", "register_envs"]
