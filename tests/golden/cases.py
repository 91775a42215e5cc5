"""Golden cases: closed-loop runs whose results are pinned by SHA-256 digests.

Every controller on its paper scenario (seeds 0 and 1), every env id under its default
action and under one fixed non-default action, and one short serial tuning run.  A
digest covers the float64 columns of the run's DataFrame (timing columns excluded), the
episode metrics, and for envs the observations and rewards of every step.  The digests
are computed with the compiled twins on and off; both must equal the stored value.

The digests hold for the BLAS kernel they were made on (``blas`` in the file; on another
kernel the tests skip, saying so, until the file is regenerated there).  The file holds
one table per mode (``compiled``, ``interpreted``): the tube MPC's
reported cost ``J`` (a diagnostic column, not a command) is summed in another order by
its compiled twin and differs in the last bit (≤ 6e-16 relative); every other digest is
the same in both tables.

On a machine whose CPU has AVX-512 (OpenBLAS picks its SkylakeX kernel, numpy its
AVX-512 loops), the Haswell digests are reproduced with both held back::

    NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" OPENBLAS_CORETYPE=Haswell \
        python -m tests.golden.cases --check

Regenerate (only in a commit whose purpose is to move numbers, saying why)::

    python -m tests.golden.cases --write
    TRAIN_ENVS_NO_JIT=1 python -m tests.golden.cases --write

Check a subset while working (names containing any of the given strings)::

    python -m tests.golden.cases --check dmc Urban004
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

GOLDEN_FILE = Path(__file__).with_name("goldens.json")

#: columns whose values depend on the machine's clock, never hashed
_TIMING = ("solve_time_s", "wall_time_s", "time_s_per", "_time_s", "elapsed")

#: controller -> its paper scenario
CONTROLLER_SCENARIOS: dict[str, str] = {
    "pid": "paper001_stopping",
    "tracking": "paper001_stopping",
    "afsmc": "paper001_stopping",
    "mpc": "paper001_stopping",
    "rmpc": "paper001_stopping",
    "rsmpc": "paper001_stopping",
    "sempc": "paper000_single_section",
    "mpc000": "paper000_single_section",
    "afsmc000": "paper000_single_section",
    "adaptive_mpc": "paper002_cruise",
    "mpc002": "paper002_cruise",
    "fuzzy_mpc": "paper003_cruise",
    "dmc": "paper004_urban",
    "fuzzy_pid": "paper004_urban",
}

#: extra scenario runs that exercise other plant features (wind, sections, real lines)
EXTRA_RUNS: dict[str, tuple[str, str]] = {
    "sempc@paper000_disturbance_harmonic": ("paper000_disturbance_harmonic", "sempc"),
    "sempc@paper000_multi_section": ("paper000_multi_section", "sempc"),
    "mpc@yizhuang": ("yizhuang", "mpc"),
    "mpc@zurich": ("zurich", "mpc"),
}

#: the fixed non-default action of the env cases (unit cube, per component)
_NON_DEFAULT = (0.35, -0.6, 0.8, -0.2, 0.5, -0.9, 0.15, 0.65, -0.4, 0.25)


class _Digest:
    def __init__(self) -> None:
        self.h = hashlib.sha256()

    def text(self, s: str) -> None:
        b = s.encode()
        self.h.update(struct.pack("<q", len(b)) + b)

    def array(self, name: str, x: Any) -> None:
        a = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
        self.text(name)
        self.text(str(a.shape))
        self.h.update(a.tobytes())

    def scalar(self, name: str, x: Any) -> None:
        self.text(name)
        if isinstance(x, (bool, np.bool_)):
            self.text(repr(bool(x)))
        elif isinstance(x, (int, float, np.integer, np.floating)):
            v = float(x)
            self.text("nan" if math.isnan(v) else v.hex())
        else:
            self.text(repr(x))

    def mapping(self, prefix: str, m: Mapping[str, Any]) -> None:
        for k in sorted(m):
            if _is_timing(k):
                continue
            v = m[k]
            if isinstance(v, Mapping):
                self.mapping(f"{prefix}{k}.", v)
            elif isinstance(v, (np.ndarray, list, tuple)) and not isinstance(v, str):
                try:
                    self.array(prefix + k, v)
                except (TypeError, ValueError):
                    self.scalar(prefix + k, repr(v))
            else:
                self.scalar(prefix + k, v)

    def hexdigest(self) -> str:
        return self.h.hexdigest()


def _is_timing(name: str) -> bool:
    return any(t in name for t in _TIMING)


def digest_result(df: Any, metrics: Mapping[str, Any]) -> str:
    """Digest of a run: float64 columns (sorted, timing excluded) and the metrics."""
    d = _Digest()
    for col in sorted(df.columns):
        if _is_timing(col):
            continue
        s = df[col]
        if s.dtype.kind in "fiub":
            d.array(col, s.to_numpy(dtype=np.float64))
    d.mapping("metric:", metrics)
    return d.hexdigest()


def run_controller(scenario: str, controller: str, seed: int) -> str:
    from train_envs.simulation import simulate

    res = simulate(scenario, controller, seed=seed)
    return digest_result(res.df, res.metrics)


def run_env(env_id: str, which: str) -> str:
    import gymnasium as gym

    import train_envs  # noqa: F401 - registers the ids
    from train_envs.envs.evaluation import params_to_action

    env = gym.make(env_id)
    try:
        obs, _ = env.reset(seed=0)
        n = env.action_space.shape[0]
        if which == "default":
            action = params_to_action(env, {})
        else:
            action = np.array([_NON_DEFAULT[i % len(_NON_DEFAULT)] for i in range(n)])
        d = _Digest()
        d.array("obs0", obs)
        done, info, k = False, {}, 0
        while not done:
            obs, r, term, trunc, info = env.step(action)
            d.array(f"obs{k}", obs)
            d.scalar(f"r{k}", r)
            k += 1
            done = term or trunc
        d.scalar("steps", k)
        d.mapping("metric:", info.get("episode_metrics", {}))
        return d.hexdigest()
    finally:
        env.close()


def run_tuning() -> str:
    from tuners.run import tune

    res = tune(
        "TrainEnvs/Urban004-v0",
        algo="mowoa",
        pop=6,
        iters=2,
        workers=1,
        backend="serial",
        storage=None,
        seeds=(0,),
        seed=3,
    )
    d = _Digest()
    ev = res.evaluations
    for col in sorted(ev.columns):
        if _is_timing(col) or col == "worker":  # worker: host:pid of the evaluation
            continue
        if ev[col].dtype.kind in "fiub":
            d.array(col, ev[col].to_numpy(dtype=np.float64))
        else:
            d.text(col)
            d.text(repr([_plain(v) for v in ev[col]]))
    if res.selected is not None:
        d.mapping("selected:", {k: _plain(v) for k, v in res.selected.items() if k != "worker"})
    d.mapping("selected_params:", res.selected_params or {})
    return d.hexdigest()


def _plain(v: Any) -> Any:
    """A repr-stable form of a stored value (arrays as float lists)."""
    if isinstance(v, np.ndarray):
        return [float(x).hex() for x in v.ravel()]
    if isinstance(v, (float, np.floating)):
        return "nan" if math.isnan(float(v)) else float(v).hex()
    return v


def cases() -> dict[str, Callable[[], str]]:
    """Case name -> function computing its digest."""
    from train_envs.envs.registration import ENV_SPECS

    out: dict[str, Callable[[], str]] = {}
    for ctrl, sc in CONTROLLER_SCENARIOS.items():
        for seed in (0, 1):
            out[f"sim:{ctrl}@{sc}:s{seed}"] = lambda sc=sc, c=ctrl, s=seed: run_controller(sc, c, s)
    for name, (sc, ctrl) in EXTRA_RUNS.items():
        out[f"sim:{name}:s0"] = lambda sc=sc, c=ctrl: run_controller(sc, c, 0)
    for env_id in ENV_SPECS:
        for which in ("default", "fixed"):
            out[f"env:{env_id}:{which}"] = lambda e=env_id, w=which: run_env(e, w)
    out["tune:Urban004-mowoa-6x2"] = run_tuning
    return out


def compute(names: list[str] | None = None) -> dict[str, str]:
    table = cases()
    return {n: table[n]() for n in (names or list(table))}


def blas_kernel() -> str:
    """The BLAS library and kernel numpy runs on (e.g. ``openblas:Haswell``): another
    kernel rounds dot products differently, and the MPCs' trajectories (OSQP at its
    iteration limit, unconstrained-first decisions near a binding row) follow."""
    import numpy  # noqa: F401 - loads numpy's BLAS
    from threadpoolctl import threadpool_info

    # other packages (scipy, solvers) may load BLAS builds of their own: numpy's counts
    blas = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    for info in sorted(blas, key=lambda i: "numpy" not in str(i.get("filepath", ""))):
        return f"{info.get('internal_api')}:{info.get('architecture')}"
    return "unknown"


def mode() -> str:
    """``compiled`` or ``interpreted``: the table this process's results belong to."""
    from train_envs import _jit

    return "compiled" if _jit.enabled() else "interpreted"


def load(which: str | None = None) -> dict[str, str]:
    """The stored digests of ``which`` mode (default: this process's)."""
    return json.loads(GOLDEN_FILE.read_text())[which or mode()]


def check(patterns: list[str]) -> int:
    """Compute the cases whose name contains any of ``patterns`` (all if none), print
    each against the stored digest of this mode; the number of mismatches."""
    stored = load()
    names = [n for n in sorted(stored) if not patterns or any(p in n for p in patterns)]
    bad = 0
    for n in names:
        got = compute([n])[n]
        ok = got == stored[n]
        bad += not ok
        print(f"{'ok  ' if ok else 'DIFF'} {n}", flush=True)
    print(f"{mode()}: {len(names) - bad} equal, {bad} different")
    return bad


if __name__ == "__main__":
    args = sys.argv[1:]
    if args[:1] == ["--check"]:
        sys.exit(1 if check(args[1:]) else 0)
    if args[:1] == ["--write"]:
        table = json.loads(GOLDEN_FILE.read_text()) if GOLDEN_FILE.exists() else {}
        table[mode()] = compute()
        table["blas"] = blas_kernel()
        GOLDEN_FILE.write_text(json.dumps(table, indent=1, sort_keys=True) + "\n")
    else:
        json.dump(compute(args or None), sys.stdout, indent=1, sort_keys=True)
