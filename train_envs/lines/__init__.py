"""Lines: track descriptions, the track catalogue and reference speed profiles."""

from train_envs.lines.catalog import (
    DEFAULT_TRAIN_FOR_TRACK,
    default_train_for_track,
    get_track,
    list_tracks,
)
from train_envs.lines.profiles import (
    SpeedProfile,
    constant_decel_profile,
    minimum_time_profile,
    paper002_speed_command,
    paper003_speed_command,
    piecewise_speed_command,
    time_supplemented_profile,
)
from train_envs.lines.track import (
    Track,
    paper000_multi_section_track,
    paper000_section_track,
    paper001_track,
    paper002_track,
    paper003_track,
    paper004_track,
)

__all__ = [
    "DEFAULT_TRAIN_FOR_TRACK",
    "SpeedProfile",
    "Track",
    "constant_decel_profile",
    "default_train_for_track",
    "get_track",
    "list_tracks",
    "minimum_time_profile",
    "paper000_multi_section_track",
    "paper000_section_track",
    "paper001_track",
    "paper002_speed_command",
    "paper002_track",
    "paper003_speed_command",
    "paper003_track",
    "paper004_track",
    "piecewise_speed_command",
    "time_supplemented_profile",
]
