"""merge_infos gives the dict of Gymnasium's VectorEnv._add_info, member by member."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.vector import VectorEnv

from train_envs.envs.vector_info import merge_infos


class _Env(VectorEnv):
    def __init__(self, n: int) -> None:
        self.num_envs = n


def _reference(infos, n):
    env, out = _Env(n), {}
    for b, info in enumerate(infos):
        if info:
            out = env._add_info(out, info, b)
    return out


def _same(a, b) -> None:
    assert list(a) == list(b)  # the same keys in the same order
    for key, va in a.items():
        vb = b[key]
        if isinstance(va, dict):
            _same(va, vb)
            continue
        assert type(va) is type(vb) and va.dtype == vb.dtype and va.shape == vb.shape, key
        if va.dtype == object:
            for x, y in zip(va.tolist(), vb.tolist(), strict=True):
                assert x is y or np.array_equal(x, y), key
        else:
            assert va.tobytes() == vb.tobytes(), key


def _random_info(rng: np.random.Generator, keys: list[str] | None = None) -> dict | None:
    """A member's info; ``keys``: exactly these keys (in a shuffled order), else a random
    subset (or None)."""
    if keys is None and rng.random() < 0.15:
        return None
    pool = {
        "f": lambda: float(rng.normal()),
        "i": lambda: int(rng.integers(-5, 5)),
        "b": lambda: bool(rng.random() < 0.5),
        "mixed": lambda: [1, 2.5, True][int(rng.integers(3))],  # int first, float later
        "np32": lambda: np.float32(rng.normal()),
        "npbool": lambda: np.bool_(rng.random() < 0.5),
        "arr": lambda: rng.normal(size=3),
        "obj": lambda: ("a", int(rng.integers(3))),
        "nan": lambda: float("nan"),
        "final_obs": lambda: rng.normal(size=2),
        "cost": lambda: {"over": float(rng.random()), "n": int(rng.integers(3))},
        "empty": lambda: {},
        "one": lambda: {"only": float(rng.random())},
    }
    keys = [k for k in pool if rng.random() < 0.7] if keys is None else list(keys)
    rng.shuffle(keys)  # members list their keys in different orders
    return {k: pool[k]() for k in keys}


@pytest.mark.parametrize("n", [1, 3, 8, 40])
def test_merge_infos_equals_add_info_member_by_member(n):
    rng = np.random.default_rng(n)
    for _ in range(50):
        infos = [_random_info(rng) for _ in range(n)]
        _same(merge_infos(infos, n), _reference(infos, n))


@pytest.mark.parametrize("n", [1, 3, 40])
def test_merge_infos_equals_add_info_when_every_member_has_the_same_keys(n):
    rng = np.random.default_rng(100 + n)
    names = ["f", "i", "b", "mixed", "np32", "npbool", "arr", "obj", "nan", "final_obs", "cost"]
    for _ in range(50):
        keys = [k for k in names + ["empty", "one"] if rng.random() < 0.6]
        if not keys:
            continue
        infos = [_random_info(rng, keys) for _ in range(n)]
        _same(merge_infos(infos, n), _reference(infos, n))
        infos[int(rng.integers(n))] = None  # one member without an info
        _same(merge_infos(infos, n), _reference(infos, n))


def test_merge_infos_of_no_info_is_empty():
    assert merge_infos([None, {}, None], 3) == {}
