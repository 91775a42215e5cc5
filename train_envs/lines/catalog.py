"""Catalogue of named tracks: the paper lines and every shipped TTOBench track.

``get_track(name)`` returns a cached, immutable :class:`~train_envs.lines.track.Track`
(``name`` may also be the path of a user's TTOBench-format JSON file);
``list_tracks()`` lists the valid names. ``DEFAULT_TRAIN_FOR_TRACK`` names the train
(see :func:`train_envs.trains.get_train`) that a run on each track uses unless told
otherwise: the paper's own train for a paper line, and for TTOBench the train that
matches the line (Beijing Yizhuang line -> Beijing subway train, Swiss lines -> FLIRT,
Swedish line -> KISS, synthetic ``00_*`` lines -> the TTOBench locomotive).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import cache
from importlib import resources
from importlib.resources.abc import Traversable

from train_envs.lines import paper_lines
from train_envs.lines.track import Track
from train_envs.validation import check_choice, is_json_path

#: Paper lines, in paper order: name -> constructor.
PAPER_TRACKS: dict[str, Callable[[], Track]] = {
    "paper000_section": paper_lines.paper000_section_track,
    "paper000_multi_section": paper_lines.paper000_multi_section_track,
    "paper001": paper_lines.paper001_track,
    "paper002": paper_lines.paper002_track,
    "paper003": paper_lines.paper003_track,
    "paper004": paper_lines.paper004_track,
}


def _ttobench_dir() -> Traversable:
    return resources.files("train_envs") / "data" / "TTOBench" / "tracks"


@cache
def _ttobench_files() -> dict[str, Traversable]:
    files = {}
    for entry in _ttobench_dir().iterdir():
        if entry.name.endswith(".json"):
            files[entry.name[: -len(".json")]] = entry
    return dict(sorted(files.items()))


def ttobench_track_ids() -> list[str]:
    """Ids of the shipped TTOBench tracks (file names without ``.json``), sorted."""
    return list(_ttobench_files())


#: Track-name prefix -> default train, first match wins (see the module docstring).
TRAIN_FOR_TRACK_PREFIX: tuple[tuple[str, str], ...] = (
    ("paper000", "paper000_dtype_metro"),
    ("paper001", "paper001_hst"),
    ("paper002", "paper002_crh3"),
    ("paper003", "paper003_shinkansen"),
    ("paper004", "paper004_btype_metro"),
    ("CN_", "CN_Beijing_Subway"),
    ("CH_", "CH_Stadler_FLIRT_TPF"),
    ("SE_", "CH_Stadler_KISS"),
    ("00_", "00_Loco_Dyn"),
)


def _default_train(name: str) -> str:
    for prefix, train in TRAIN_FOR_TRACK_PREFIX:
        if name.startswith(prefix):
            return train
    raise ValueError(f"no default train rule for track {name!r}")


def list_tracks() -> list[str]:
    """Every catalogue track name: the paper lines, then the TTOBench ids (sorted)."""
    return list(PAPER_TRACKS) + ttobench_track_ids()


#: Default train name for every catalogue track.
DEFAULT_TRAIN_FOR_TRACK: dict[str, str] = {name: _default_train(name) for name in list_tracks()}


@cache
def get_track(name: str | os.PathLike[str]) -> Track:
    """Return the catalogue track ``name`` (cached; the object is immutable), or the
    track of a user's TTOBench-format JSON file when ``name`` is a path (ends in
    ``.json`` or holds a directory separator).

    Raises ``ValueError`` listing the valid names for an unknown ``name``, and one
    naming the file for an unreadable or invalid file.
    """
    if is_json_path(name):
        return Track.from_ttobench(os.fspath(name))
    if not isinstance(name, str):
        raise ValueError(f"track must be a catalogue name or a JSON path, got {name!r}")
    if name in PAPER_TRACKS:
        return PAPER_TRACKS[name]()
    files = _ttobench_files()
    check_choice("track", name, list_tracks())
    return Track.from_ttobench(files[name])


def default_train_for_track(name: str) -> str:
    """Name of the default train for catalogue track ``name``."""
    check_choice("track", name, list(DEFAULT_TRAIN_FOR_TRACK))
    return DEFAULT_TRAIN_FOR_TRACK[name]
