"""Speed of two source trees side by side: the same benchmark scripts, alternating rounds.

Run::

    python benchmarks/compare_trees.py --old ../old-tree --new . --rounds 4 \\
        "benchmarks/bench_envs.py --episodes 1" "benchmarks/bench_train_mpc.py --episodes 1"

Each benchmark command runs as a separate process with ``PYTHONPATH`` set to one tree
(the script itself is taken from the ``--new`` tree, so both trees run the same
measurement code through the library's public names), old and new in turn, the order
swapped every round so that drifts of the machine's speed hit both alike.  Every
markdown table row the scripts print is parsed: cells whose header names a time
(``µs``, ``[s]``, ``ms``) or a rate (``/s``, ``factor``) are compared, as a speed ratio
``new speed / old speed`` (``old time / new time`` or ``new rate / old rate``), per
round.  The report lists, per benchmark, the median over rounds and rows of those
ratios, and per row the median over rounds; 1.00 = same speed, above 1 = new faster.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import statistics
import subprocess
import sys
from pathlib import Path

_TIME = re.compile(r"µs|\[s\]|\bms\b|wall")
_RATE = re.compile(r"/s\b|factor|per s")
_NUM = re.compile(r"^-?\d+(\.\d+)?(e[-+]?\d+)?$")


def _tables(text: str) -> dict[tuple[str, str], float]:
    """(row label, column header) -> value of every timing or rate cell of every table:
    rates as +value, times as −value (the sign tells :func:`_speed` which kind)."""
    out: dict[tuple[str, str], float] = {}
    header: list[str] | None = None
    for line in text.splitlines():
        line = line.strip()
        if not line.startswith("|"):
            header = None
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if header is None:
            header = cells
            continue
        if all(set(c) <= set("-: ") for c in cells):
            continue
        label = " / ".join(c for c in cells if not _NUM.match(c.split(" ")[0] or "x"))
        for h, c in zip(header, cells, strict=False):
            parts = [p for p in c.replace("/", " ").split() if _NUM.match(p)]
            if not parts or "%" in c:
                continue
            value = float(parts[0])
            if value <= 0:
                continue
            if _RATE.search(h) and not _TIME.search(h.replace("wall", "")):
                out[(label, h)] = value  # rate: higher is faster
            elif _TIME.search(h) or "[s]" in h:
                out[(label, h)] = -value  # time: lower is faster (sign tags the kind)
    return out


def _run(tree: Path, script_tree: Path, cmd: str) -> dict[tuple[str, str], float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    argv = shlex.split(cmd)
    argv[0] = str(script_tree / argv[0])
    res = subprocess.run(
        [sys.executable, *argv], cwd=tree, env=env, capture_output=True, text=True, check=False
    )
    if res.returncode != 0:
        raise SystemExit(f"{cmd} failed in {tree}:\n{res.stderr[-3000:]}")
    return _tables(res.stdout)


def _speed(old: float, new: float) -> float:
    return (new / old) if old > 0 else (old / new)  # rates: new/old; times: old/new


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True)
    ap.add_argument("--new", type=Path, default=Path("."))
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("commands", nargs="+")
    args = ap.parse_args()
    old, new = args.old.resolve(), args.new.resolve()
    print("| benchmark | cells | median speed ratio new/old | min | max | rounds |")
    print("|---|---:|---:|---:|---:|---:|")
    for cmd in args.commands:
        per_cell: dict[tuple[str, str], list[float]] = {}
        for r in range(args.rounds):
            order = [(old, "old"), (new, "new")] if r % 2 == 0 else [(new, "new"), (old, "old")]
            got = {tag: _run(tree, new, cmd) for tree, tag in order}
            for key in got["old"].keys() & got["new"].keys():
                per_cell.setdefault(key, []).append(_speed(got["old"][key], got["new"][key]))
        cells = {k: statistics.median(v) for k, v in per_cell.items()}
        allr = [x for v in per_cell.values() for x in v]
        med = statistics.median(cells.values()) if cells else float("nan")
        print(
            f"| `{cmd}` | {len(cells)} | {med:.3f} | {min(allr, default=float('nan')):.3f} | "
            f"{max(allr, default=float('nan')):.3f} | {args.rounds} |",
            flush=True,
        )
        for (label, h), v in sorted(cells.items()):
            print(f"|   {label} — {h} | | {v:.3f} | | | |", file=sys.stderr)


if __name__ == "__main__":
    main()
