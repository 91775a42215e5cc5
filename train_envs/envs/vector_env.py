"""A native Gymnasium vector env: B tuning envs whose closed loops step in lockstep.

:class:`TrainTuningVectorEnv` is ``num_envs`` copies of
:class:`~train_envs.envs.train_env.TrainTuningEnv` of one id and config whose plants and
inner controllers run as one :class:`~train_envs.simulation.batch.BatchLoop` (batched
plant and controller). Each member keeps its own env object for what is per member
and cheap: the action decoding, the seeding and scenario draw of its reset, the
observation features and the rewards, which read the member's rows of the batched
runner through a :class:`MemberLoop` view. So member ``i`` gives what a single env
gives with the same seed and actions, bit for bit (tested).

An env that draws a station-to-station section per episode (the real-line ids) runs
one batched runner per section its members are on: member ``b`` lives in the runner of
its current section (the other runners keep its slot idle), moves when a reset draws
another section, and a runner without members is dropped. The members' envs share one
cache of section scenarios, so members on one section share its scenario object.

Autoreset follows Gymnasium 1.x's default, :attr:`AutoresetMode.NEXT_STEP`: the step
after a member's episode ended resets that member (its action is ignored, reward 0,
not terminated or truncated, the reset's observation and info). ``reset(seed=s)``
seeds member ``i`` with ``s + i`` (a list: one seed each), as
:class:`gymnasium.vector.SyncVectorEnv` does; ``options={"reset_mask": mask}`` resets
only the members of the mask (the others keep their last observation). Infos are
merged per key with ``_key`` masks, as :meth:`VectorEnv._add_info` merges them
(:func:`~train_envs.envs.vector_info.merge_infos`, one pass per key). Registered as the
``vector_entry_point`` of every id (:func:`train_envs.envs.registration.register_envs`):
single-car members on the batched single-car plant, multi-car members (one whole-train
input or one input per car) on the batched multi-car plant, where :class:`MemberLoop`
gives the env the coupler columns and the per-car commands' total as the single
runner does. A plant the lockstep runner does not batch
(:func:`~train_envs.simulation.batch.batchable_member`) and
``supervision.end_on_violation`` are refused with a ``ValueError``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from train_envs.envs.train_env import TrainTuningEnv
from train_envs.envs.vector_info import merge_infos
from train_envs.simulation.batch import BatchLoop, batchable_member

__all__ = ["MemberLoop", "TrainTuningVectorEnv"]


class _MemberPlant:
    """Member ``b``'s read-outs of the batched plant (what the env's parts read): the
    lead car's time, position, speed and acceleration, the traction and braking work,
    and the number of cars ``n`` (the reward's coupler terms on multi-car trains)."""

    def __init__(self, loop: BatchLoop, b: int) -> None:
        self._p = loop.plant
        self._b = b
        self.n = loop.n_cars

    @property
    def t(self) -> float:
        return float(self._p.t[self._b])

    @property
    def s(self) -> float:
        return float(self._p.s[self._b])

    @property
    def v(self) -> float:
        return float(self._p.v[self._b])

    @property
    def accel(self) -> float:
        return float(self._p.accel()[self._b])

    @property
    def work_traction_J(self) -> float:
        return float(self._p.work_traction_J[self._b])

    @property
    def work_brake_J(self) -> float:
        return float(self._p.work_brake_J[self._b])


class MemberLoop:
    """Member ``b`` of a :class:`BatchLoop` as the parts of a ClosedLoop an env reads:
    the step count ``k``, the last command ``u_prev`` (an array of ``n_inputs``: one
    whole-train input, or one per car), the controller's ``last_info``, the end of
    episode (``terminated``, ``truncated``, ``done``; ``safety_end`` is always None: the
    batched runner has no ``end_on_violation``), the recorded ``columns`` (with the
    coupler columns on multi-car trains), the episode ``metrics`` and the ``plant``'s
    read-outs (single-car and multi-car members alike)."""

    safety_end = None

    def __init__(self, loop: BatchLoop, b: int) -> None:
        self._loop = loop
        self._b = b
        self.plant = _MemberPlant(loop, b)
        self.scenario = loop.scenario

    @property
    def k(self) -> int:
        return int(self._loop.k[self._b])

    @property
    def u_prev(self) -> np.ndarray:
        u = self._loop.u_prev
        return u[self._b].copy() if u.ndim == 2 else np.array([u[self._b]])

    @property
    def last_info(self) -> Mapping[str, float]:
        return self._loop.last_info(self._b)

    @property
    def terminated(self) -> bool:
        return bool(self._loop.terminated[self._b])

    @property
    def truncated(self) -> bool:
        return bool(self._loop.truncated[self._b])

    @property
    def done(self) -> bool:
        return bool(self._loop.done[self._b])

    def columns(self, k0: int, k1: int, names: Sequence[str]) -> dict[str, np.ndarray]:
        data = self._loop._data
        return {name: data[name][k0:k1, self._b] for name in names}

    def metrics(self) -> dict[str, float]:
        return self._loop.metrics(self._b)


class TrainTuningVectorEnv(VectorEnv):
    """``num_envs`` tuning envs of one id stepping in one process (see the module doc).

    Args:
        num_envs: the number of members B.
        base_config, config: as :class:`TrainTuningEnv` (the id's settings, overrides).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        config: Mapping[str, Any] | None = None,
        base_config: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        from train_envs.envs.batch import lockstep_builder

        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if kwargs.pop("render_mode", None) is not None:
            raise ValueError("TrainTuningVectorEnv has no render mode")
        kwargs.pop("max_episode_steps", None)  # (the env's own cap: episode.max_steps)
        if kwargs:
            raise ValueError(f"unknown arguments {sorted(kwargs)}")
        self.num_envs = num_envs
        self.envs = [TrainTuningEnv(config, base_config=base_config) for _ in range(num_envs)]
        e0 = self.envs[0]
        for env in self.envs[1:]:  # one scenario object per section for all members
            env._section_cache = e0._section_cache
        e0.reset(seed=0)
        plant = e0.loop.plant
        if not batchable_member(plant):
            raise ValueError(
                f"the plant of scenario {e0.scenario.name!r} is not one the lockstep runner "
                "batches: use gymnasium.make_vec(..., vectorization_mode='sync')"
            )
        if e0.loop.supervision.end_on_violation:
            raise ValueError(
                "supervision.end_on_violation is not supported by the lockstep runner: use "
                "gymnasium.make_vec(..., vectorization_mode='sync')"
            )
        self._builder = lockstep_builder(e0.controller, plant.n)
        e0._np_random = None  # (drawn anew, as a fresh env's, on a reset without a seed)
        self._real_loops = [e.loop for e in self.envs]
        self.single_action_space = e0.action_space
        self.single_observation_space = e0.observation_space
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        #: the batched runner per scenario (id) the members are on, member b's runner
        self._loops: dict[int, BatchLoop] = {}
        self._home: list[BatchLoop] = []
        self._views: list[MemberLoop] = []
        self._pending = np.zeros(num_envs, dtype=bool)
        self.config = e0.config

    @property
    def loop(self) -> BatchLoop | None:
        """The batched runner member 0 is on (None before the first reset)."""
        return self._home[0] if self._home else None

    # ------------------------------------------------------------------ reset
    def _bind(self, b: int) -> np.ndarray:
        """Bind member ``b``'s env parts to its view of the batched runner (after the
        env's reset); returns its first observation."""
        env = self.envs[b]
        view = self._views[b]
        self._home[b].controller.set_params(b, env.controller.get_params())
        env.loop = view
        env.observation_type.bind(env.scenario, view)
        env.reward_type.bind(env.scenario, view)
        return env.observation_type.observe()

    def _reset_member(self, b: int, seed: int | None, options: Any) -> tuple[np.ndarray, dict]:
        """Reset member ``b`` through its env (seed, scenario draw, plant), then run it
        on the batched runner."""
        env = self.envs[b]
        env.loop = self._real_loops[b]
        _, info = env.reset(seed=seed, options=options)
        old, sc = self._home[b], env.scenario
        loop = self._loops.get(id(sc))
        if loop is None:  # the first member on this section: a runner for it
            loop = self._runner(sc, [b])
        loop.reset_member(b, env.loop.plant)
        if loop is not old:
            old.done[b] = True  # (its slot there stays idle: steps are always masked)
            self._home[b] = loop
            self._views[b] = MemberLoop(loop, b)
            if all(home is not old for home in self._home):
                del self._loops[id(old.scenario)]
        self._pending[b] = False
        return self._bind(b), info

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=None)
        B = self.num_envs
        if seed is None or isinstance(seed, int):
            seeds = [None if seed is None else seed + i for i in range(B)]
        else:
            seeds = list(seed)
            if len(seeds) != B:
                raise ValueError(f"seed must hold num_envs={B} seeds, got {len(seeds)}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        obs = np.zeros(self.observation_space.shape, dtype=self.single_observation_space.dtype)
        infos: list[dict[str, Any] | None] = [None] * B
        if mask is None:  # every member: a new batched runner
            for b, env in enumerate(self.envs):
                env.loop = self._real_loops[b]
                infos[b] = env.reset(seed=seeds[b], options=options or None)[1]
            self._build()
            for b in range(B):
                obs[b] = self._bind(b)
            self._pending[:] = False
            self._obs = obs.copy()
            return obs, merge_infos(infos, B)
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (B,):
            raise ValueError(f"options reset_mask must be a ({B},) boolean array")
        if self.loop is None:
            raise ValueError("reset with a reset_mask needs a first full reset")
        for b in range(B):
            if mask[b]:
                obs[b], infos[b] = self._reset_member(b, seeds[b], options or None)
            else:  # the members left alone: their last observation
                obs[b] = self._obs[b]
        self._obs = obs.copy()
        return obs, merge_infos(infos, B)

    def _runner(self, sc: Any, members: Sequence[int]) -> BatchLoop:
        """A batched runner of scenario ``sc`` with a slot per member, ``members`` (on
        ``sc``, freshly reset) active in it and the other slots idle (holding the first
        member's plant state until a member moves in)."""
        envs = self.envs
        first = envs[members[0]]
        params = [e.controller.get_params() for e in envs]
        ctrl = self._builder(first, params, lambda b: envs[b].controller)
        on = set(members)
        plants = [(e if b in on else first).loop.plant for b, e in enumerate(envs)]
        loop = BatchLoop(sc, plants, ctrl, first.loop.supervision)
        for b in range(self.num_envs):
            if b not in on:
                loop.done[b] = True
        self._loops[id(sc)] = loop
        return loop

    def _build(self) -> None:
        """New batched runners over the members' freshly reset plants, one per scenario
        drawn."""
        groups: dict[int, list[int]] = {}
        for b, env in enumerate(self.envs):
            groups.setdefault(id(env.scenario), []).append(b)
        self._loops = {}
        self._home = [None] * self.num_envs  # type: ignore[list-item]
        for members in groups.values():
            loop = self._runner(self.envs[members[0]].scenario, members)
            for b in members:
                self._home[b] = loop
        self._views = [MemberLoop(self._home[b], b) for b in range(self.num_envs)]

    # ------------------------------------------------------------------ step
    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self.loop is None:
            raise RuntimeError("step() called before reset()")
        B = self.num_envs
        actions = np.asarray(actions)
        if actions.shape != self.action_space.shape:
            raise ValueError(
                f"actions must have shape {self.action_space.shape}, got {actions.shape}"
            )
        envs, home = self.envs, self._home
        obs = np.zeros(self.observation_space.shape, dtype=self.single_observation_space.dtype)
        rewards = np.zeros(B)
        terms = np.zeros(B, dtype=bool)
        truncs = np.zeros(B, dtype=bool)
        infos: list[dict[str, Any] | None] = [None] * B
        run = ~self._pending
        clipped = [0] * B
        params: list[dict[str, float]] = [{}] * B
        for b in np.flatnonzero(run).tolist():
            clipped[b], params[b] = envs[b]._act(actions[b])
            home[b].controller.set_params(b, params[b])
        k0 = [int(home[b].k[b]) for b in range(B)]
        running = run.copy()
        loops = [(loop, np.array([h is loop for h in home])) for loop in self._loops.values()]
        for _ in range(envs[0]._n_ctrl):
            if not running.any():
                break
            for loop, members in loops:
                mask = running & members
                if mask.any():
                    loop.step(mask)
                    running &= ~(loop.done & members)
        for b in range(B):
            env = envs[b]
            if not run[b]:  # next-step autoreset
                obs[b], infos[b] = self._reset_member(b, None, None)
                continue
            env._steps += 1
            env._clipped_total += clipped[b]
            term, trunc = env._episode_end()
            final = term or trunc
            costs = env._costs(k0[b], final)
            rewards[b] = env._reward(costs)
            info = env._info(clipped[b], params[b], costs, final)
            obs[b] = env._observe()
            terms[b], truncs[b] = term, trunc
            self._pending[b] = final
            infos[b] = info
        self._obs = obs.copy()
        return obs, rewards, terms, truncs, merge_infos(infos, B)

    def close_extras(self, **kwargs: Any) -> None:
        for env in self.envs:
            env.close()
