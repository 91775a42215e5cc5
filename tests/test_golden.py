"""Golden trajectories: every controller, env and a short tuning run, bit for bit.

The digests in ``tests/golden/goldens.json`` pin the results of the cases listed in
:mod:`golden.cases`.  They are checked with the compiled twins on (in this process) and
off (``TRAIN_ENVS_NO_JIT=1``, in subprocesses); both must equal the stored digest.  A
change that moves numbers re-baselines the file in its own commit and says why.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from golden import cases as golden

ROOT = Path(__file__).resolve().parents[1]
if json.loads(golden.GOLDEN_FILE.read_text())["blas"] != golden.blas_kernel():
    pytest.skip(
        f"goldens made on BLAS kernel {json.loads(golden.GOLDEN_FILE.read_text())['blas']}, "
        f"this machine runs {golden.blas_kernel()}: see golden.cases to check them here",
        allow_module_level=True,
    )
STORED = golden.load("compiled")
INTERPRETED = golden.load("interpreted")
NAMES = sorted(STORED)
#: the interpreted runs are split into this many subprocesses (spread over xdist workers)
CHUNKS = 6


def test_every_case_has_a_golden():
    assert sorted(golden.cases()) == NAMES == sorted(INTERPRETED)


def test_modes_differ_only_in_the_tube_mpc_cost_diagnostic():
    differ = sorted(n for n in NAMES if STORED[n] != INTERPRETED[n])
    assert all(n.startswith(("sim:rmpc@", "sim:rsmpc@")) for n in differ), differ


@pytest.mark.parametrize("name", NAMES)
def test_compiled_twins_on(name):
    assert golden.compute([name])[name] == golden.load()[name]


def _chunks() -> list[list[str]]:
    return [NAMES[i::CHUNKS] for i in range(CHUNKS)]


@pytest.mark.parametrize("chunk", range(CHUNKS))
def test_compiled_twins_off(chunk):
    names = _chunks()[chunk]
    env = {**os.environ, "TRAIN_ENVS_NO_JIT": "1", "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-m", "tests.golden.cases", *names],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-4000:]
    got = json.loads(out.stdout)
    wrong = [n for n in names if got[n] != INTERPRETED[n]]
    assert not wrong, f"digests changed with the compiled twins off: {wrong}"
