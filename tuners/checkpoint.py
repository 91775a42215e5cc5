"""Resume by replay: a checkpoint is data, the algorithm is rebuilt and replayed.

A study's checkpoint (:func:`tuners.storage.read_checkpoint`, schema
:data:`tuners.storage.CHECKPOINT_SCHEMA`) holds no algorithm object: the number of
generations done, the termination schedule they ran under, and digests of the
algorithm's state after the last one (:func:`tuners.storage.algorithm_state`). The
pymoo algorithms of :mod:`tuners.run` are deterministic given their seed and the
evaluation results, and every finished evaluation is in the study, so a freshly
constructed algorithm with the stored settings, advanced generation by generation with
every evaluation answered from the cache, reaches exactly the checkpointed state;
:func:`replay` checks that against the digests and refuses a diverged replay.

Cost: the algorithm's own work per generation, no episode.
"""

from __future__ import annotations

from typing import Any

from pymoo.core.callback import Callback
from pymoo.termination.max_gen import MaximumGenerationTermination

from tuners.storage import algorithm_state

__all__ = ["generations_done", "iters_at", "replay", "set_iters"]


def generations_done(algorithm: Any) -> int:
    """Generations the algorithm has finished (0 before the first)."""
    return int(algorithm.n_iter) - 1 if getattr(algorithm, "is_initialized", False) else 0


def iters_at(schedule: list[list[int]], generation: int) -> int:
    """The ``iters`` that generation ``generation`` runs under in ``schedule``."""
    iters = schedule[0][1]
    for first, n in schedule:
        if first <= generation:
            iters = n
    return int(iters)


def set_iters(algorithm: Any, iters: int) -> None:
    """Give the algorithm a generation budget of ``iters`` (progress kept)."""
    term = MaximumGenerationTermination(int(iters))
    term.perc = generations_done(algorithm) / int(iters)
    algorithm.termination = term


def replay(algorithm: Any, checkpoint: dict[str, Any], study_name: str) -> None:
    """Advance a freshly set-up ``algorithm`` to the checkpoint's generation.

    The algorithm's problem must answer the stored evaluations (its runner's cache).
    Its callback is not called for the replayed generations. ``ValueError`` if the
    replayed state differs from the checkpoint's digests.
    """
    target = int(checkpoint["n_gen"])
    schedule = checkpoint["schedule"]
    callback, algorithm.callback = algorithm.callback, Callback()
    try:
        while generations_done(algorithm) < target:
            iters = iters_at(schedule, generations_done(algorithm) + 1)
            if getattr(algorithm.termination, "n_max_gen", None) != iters:
                set_iters(algorithm, iters)
            algorithm.next()
    finally:
        algorithm.callback = callback
    state = algorithm_state(algorithm)
    if state != checkpoint["state"]:
        raise ValueError(
            f"cannot resume study {study_name!r}: replaying its {target} generations gave "
            f"another algorithm state (stored {checkpoint['state']}, replayed {state}); its "
            "evaluations do not reproduce the run (edited study or non-deterministic code)"
        )
