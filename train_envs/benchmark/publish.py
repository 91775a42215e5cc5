"""Put benchmark leaderboards into a Markdown document, between markers.

Usage (the published tables of ``docs/benchmark.md``)::

    python -m train_envs.benchmark.publish default results/benchmark [--doc docs/benchmark.md]
    python -m train_envs.benchmark.publish tuned results/benchmark-tuned

reads ``<folder>/leaderboard.csv`` and ``results.csv`` and replaces the text between
``<!-- leaderboard:<name> -->`` and ``<!-- /leaderboard:<name> -->`` in the document
with a one-line summary (pairs by status, parameters, disturbance, seeds, runs) and the
leaderboard's tables (:func:`train_envs.benchmark.leaderboard_markdown`).
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pandas as pd

from train_envs.benchmark.leaderboard import leaderboard_markdown

__all__ = ["publish", "summary_markdown"]


def summary_markdown(folder: str | Path) -> str:
    """The summary line and leaderboard tables of a benchmark folder."""
    folder = Path(folder)
    board = pd.read_csv(folder / "leaderboard.csv", dtype={"note": str}, keep_default_na=True)
    board["note"] = board["note"].fillna("")
    table = pd.read_csv(folder / "results.csv")
    seeds = sorted({int(s) for s in table["seed"]}) if len(table) else []
    counts = board["status"].value_counts().to_dict()
    tuned = board["parameters"].dropna().map(json.loads).map(bool).any()
    dists = sorted(board["disturbance"].dropna().unique()) if "disturbance" in board else []
    dist = f"disturbance {', '.join(map(str, dists))}; " if dists else ""
    head = (
        f"{len(board)} pairs ({', '.join(f'{n} {k}' for k, n in counts.items())}); "
        f"{'tuned' if tuned else 'default'} parameters; {dist}seeds {seeds}; "
        f"{len(table)} runs. "
        "Each value: mean ± half-width of the 95 % t interval over the seeds."
    )
    return head + "\n\n" + leaderboard_markdown(board)


def publish(name: str, folder: str | Path, doc: str | Path) -> Path:
    """Replace the ``name`` block of ``doc`` with the leaderboard of ``folder``."""
    doc = Path(doc)
    text = doc.read_text()
    start, end = f"<!-- leaderboard:{name} -->", f"<!-- /leaderboard:{name} -->"
    pattern = re.compile(re.escape(start) + ".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise ValueError(f"{doc} has no block {start} ... {end}")
    block = f"{start}\n{summary_markdown(folder)}\n{end}"
    doc.write_text(pattern.sub(lambda _: block, text, count=1))
    return doc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m train_envs.benchmark.publish")
    p.add_argument("name", help="the block to replace: default or tuned")
    p.add_argument("folder", help="the benchmark's --out folder")
    p.add_argument("--doc", default="docs/benchmark.md", help="(default docs/benchmark.md)")
    args = p.parse_args(argv)
    print(f"wrote {publish(args.name, args.folder, args.doc)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
