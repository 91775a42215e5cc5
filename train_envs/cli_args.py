"""Argument parsing shared by every ``train-envs`` subcommand (simulate, tune, train, ...),
and the entry-point lookup through which the packages built on ``train_envs`` add theirs.

Nothing here imports a layer above ``train_envs``: a subcommand or reproduction of the
tuners or agents is found by name in the installed package metadata
(``[project.entry-points."<group>"]`` in ``pyproject.toml``) and imported only when used.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

#: group of ``add(subparsers)`` functions that add subcommands to ``train-envs``
CLI_GROUP = "train_envs.cli"
#: group of ``reproduce_paperNNN(seed=0) -> DataFrame`` functions of ``train-envs reproduce``
REPRODUCE_GROUP = "train_envs.reproduce"


def registered(group: str) -> dict[str, EntryPoint]:
    """The entry points of ``group`` by name, in name order (not loaded)."""
    return {ep.name: ep for ep in sorted(entry_points(group=group), key=lambda ep: ep.name)}


def parse_seeds(items: list[str] | None, flag: str = "--seeds") -> list[int] | None:
    """Seeds as ``0 1 2``, ``0,1,2`` or inclusive ranges ``0-4``; ``None`` if none given.

    Seeds are integers >= 0; a range a-b needs a <= b; ``ValueError`` naming the flag.
    """
    if not items:
        return None
    out: list[int] = []
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            try:
                lo, _, hi = part.partition("-") if "-" in part[1:] else (part, "", part)
                lo_i, hi_i = int(lo), int(hi)
            except ValueError as exc:
                raise ValueError(f"{flag}: {part!r} is not an integer >= 0 or a range a-b") from exc
            if lo_i < 0:
                raise ValueError(f"{flag}: seeds are integers >= 0, got {part!r}")
            if hi_i < lo_i:
                raise ValueError(f"{flag}: range {part!r} is empty (write a-b with a <= b)")
            out.extend(range(lo_i, hi_i + 1))
    if not out:
        raise ValueError(f"{flag}: no seed given")
    return out


def writable_folder(path: str | Path, flag: str = "--out") -> Path:
    """Create folder ``path`` if needed and check that a file can be written there."""
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ValueError(
            f"{flag}: folder {str(folder)!r} is not writable ({exc.strerror})"
        ) from exc
    return folder


def json_object(text: str | None, flag: str) -> dict[str, Any] | None:
    """A JSON object given inline or as ``@file.json``; ``None`` if empty."""
    if not text:
        return None
    if text.startswith("@"):
        try:
            text = Path(text[1:]).read_text()
        except OSError as exc:
            raise ValueError(f"{flag}: cannot read {text[1:]!r} ({exc.strerror})") from exc
    try:
        val = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{flag} must be JSON (or @file.json): {exc}") from exc
    if not isinstance(val, dict):
        raise ValueError(f"{flag} must be a JSON object")
    return val


def key_values(
    items: list[str] | None,
    flag: str,
    convert: Callable[[str], Any] = float,
    form: str = "KEY=VALUE",
) -> dict[str, Any]:
    """``KEY=VALUE`` pairs with each value converted; errors name the flag."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"{flag} expects {form}, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = convert(v)
        except ValueError as exc:
            raise ValueError(f"{flag} {k}: value {v!r} is not valid ({exc})") from exc
    return out
