"""Minimum running time of every station-to-station section of the shipped TTOBench tracks.

Each track is run with its default train (``DEFAULT_TRAIN_FOR_TRACK``) using
:func:`train_envs.lines.minimum_time_profile` (full traction, service braking, no speed
margin). Prints a Markdown table; ``--csv PATH`` also writes it as CSV.

Usage::

    python benchmarks/profile_running_times.py [--ds 1.0] [--csv out.csv] [--papers]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

from train_envs.lines import minimum_time_profile
from train_envs.lines.catalog import (
    DEFAULT_TRAIN_FOR_TRACK,
    PAPER_TRACKS,
    get_track,
    ttobench_track_ids,
)
from train_envs.trains import KMH, get_train

COLUMNS = ["track", "train", "from_m", "to_m", "length_m", "min_time_s", "mean_speed_kmh"]


def running_time_table(track_names: list[str], ds: float = 1.0) -> pd.DataFrame:
    """One row per consecutive stop pair of each track: the minimum running time."""
    rows = []
    for name in track_names:
        track = get_track(name)
        train_name = DEFAULT_TRAIN_FOR_TRACK[name]
        train = get_train(train_name)
        for s_from, s_to in track.station_pairs:
            prof = minimum_time_profile(track, train, s_from, s_to, ds=ds)
            length = s_to - s_from
            t = prof.running_time_s
            rows.append(
                {
                    "track": name,
                    "train": train_name,
                    "from_m": s_from,
                    "to_m": s_to,
                    "length_m": length,
                    "min_time_s": t,
                    "mean_speed_kmh": length / t / KMH,
                }
            )
    return pd.DataFrame(rows, columns=COLUMNS)


def to_markdown(df: pd.DataFrame) -> str:
    """Render the table as GitHub Markdown (no optional dependency needed)."""
    fmt = {
        "from_m": "{:.1f}",
        "to_m": "{:.1f}",
        "length_m": "{:.1f}",
        "min_time_s": "{:.1f}",
        "mean_speed_kmh": "{:.1f}",
    }
    lines = ["| " + " | ".join(COLUMNS) + " |"]
    align = ["---" if c in ("track", "train") else "---:" for c in COLUMNS]
    lines.append("|" + "|".join(align) + "|")
    for row in df.itertuples(index=False):
        cells = [fmt.get(c, "{}").format(getattr(row, c)) for c in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ds", type=float, default=1.0, help="grid step [m] (default 1.0)")
    parser.add_argument("--csv", type=Path, default=None, help="also write the table as CSV")
    parser.add_argument(
        "--papers", action="store_true", help="also include the paper lines of the catalogue"
    )
    args = parser.parse_args(argv)
    names = ttobench_track_ids() + (list(PAPER_TRACKS) if args.papers else [])
    t0 = time.perf_counter()
    df = running_time_table(names, ds=args.ds)
    elapsed = time.perf_counter() - t0
    print(to_markdown(df))
    print(f"\n{len(df)} sections, ds = {args.ds:g} m, computed in {elapsed:.2f} s")
    if args.csv is not None:
        df.to_csv(args.csv, index=False)
        print(f"CSV written to {args.csv}")


if __name__ == "__main__":
    main()
