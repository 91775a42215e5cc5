"""The info dict of a vector env from its members' infos, built key by key.

Gymnasium's :meth:`gymnasium.vector.VectorEnv._add_info` merges one member's info at a
time: for every key it makes (on the key's first member) an array over the members --
``dtype`` the type of that first value for Python ``int``/``float``/``bool`` and numpy
scalars, the value's own ``dtype`` and shape for an array, ``object`` otherwise; nested
dicts recursively; ``final_obs`` always an object array -- writes the member's entry,
and keeps a boolean mask ``_key`` of the members that have the key: a Python call per
member and key, which a vector env of tens of members pays at every step.

:func:`merge_infos` gives the same dict -- keys in the same order, the same arrays,
dtypes and masks -- in one pass per key: where every value of a key is a Python
``float``, or every one an ``int``, or every one a ``bool`` (the common case), they are
written with one fancy-index assignment (into the array of their own type: the values
themselves); anything else is written member by member, as Gymnasium does. Tested
against ``_add_info`` applied member by member.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["merge_infos"]

_PLAIN = (float, int, bool)


def merge_infos(infos: Sequence[dict[str, Any] | None], num_envs: int) -> dict[str, Any]:
    """The vector info of ``infos`` (member ``b``'s info, or None where it has none):
    equal to ``VectorEnv._add_info`` applied to the members in order ``b = 0, 1, ...``
    on an empty dict."""
    return _merge([(b, info) for b, info in enumerate(infos) if info], num_envs)


def _merge(items: list[tuple[int, dict[str, Any]]], n: int) -> dict[str, Any]:
    keys: dict[str, None] = {}  # the keys in the order of their first member
    for _, info in items:
        for key in info:
            keys[key] = None
    out: dict[str, Any] = {}
    for key in keys:
        present = [(b, info[key]) for b, info in items if key in info]
        idx = [b for b, _ in present]
        first = present[0][1]
        if key == "final_obs":
            array: Any = np.full(n, fill_value=None, dtype=object)
            for b, value in present:
                array[b] = value
        elif isinstance(first, dict):
            # (as _add_info: a member whose value is not a dict would break there)
            array = _merge(present, n)
        else:
            if type(first) in _PLAIN or issubclass(type(first), np.number):
                array = np.zeros(n, dtype=type(first))
            elif isinstance(first, np.ndarray):
                array = np.zeros((n, *first.shape), dtype=first.dtype)
            else:
                array = np.full(n, fill_value=None, dtype=object)
            values = [v for _, v in present]
            kind = type(first)
            if kind in _PLAIN and all(type(v) is kind for v in values):
                array[idx] = values
            else:
                for b, value in present:
                    array[b] = value
        mask = np.zeros(n, dtype=np.bool_)
        mask[idx] = True
        out[key], out[f"_{key}"] = array, mask
    return out
