"""Test helper: wait until a tuning process has stored trials in its SQLite study."""

from __future__ import annotations

import sqlite3
import subprocess
import time
from pathlib import Path


def wait_for_trials(
    dbfile: Path, n: int, proc: subprocess.Popen, timeout: float = 90, poll_s: float = 0.1
) -> int:
    """Poll the SQLite study file until it holds ``n`` trials; the count seen.

    Raises ``AssertionError`` if the process ends or the time runs out first.
    """
    deadline = time.time() + timeout
    seen = 0
    while time.time() < deadline and proc.poll() is None:
        if dbfile.exists():
            try:
                with sqlite3.connect(dbfile, timeout=1) as con:
                    seen = con.execute("select count(*) from trials").fetchone()[0]
            except sqlite3.Error:
                seen = 0
            if seen >= n:
                return seen
        time.sleep(poll_s)
    raise AssertionError(f"the writer stored {seen} < {n} trials (rc {proc.poll()})")
