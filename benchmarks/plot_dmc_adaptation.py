"""Figure: paper 004's DMC on ``paper004_urban`` with its online adjustments.

Runs the default :class:`~train_envs.controllers.dmc.DMCController` (or the one given by
``--param name=value``) on ``paper004_urban`` and saves five stacked panels over time:

1. speed v and reference v_ref,
2. speed error v_ref − v (clipped to ±0.12 m/s) with the gradient on a second axis,
3. softening factor α(t) with the bounds α_min, α_max,
4. correction coefficient h_c(t) with h_0,
5. fuzzy satisfaction index J(t) with its parts μ_t and μ_y.

Usage::

    python benchmarks/plot_dmc_adaptation.py --out dmc_adaptation.png [--param k_h=0.1]

Not a test. Prints the run's metrics.
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from train_envs.controllers.dmc import DMCController  # noqa: E402
from train_envs.scenarios import get_scenario  # noqa: E402
from train_envs.simulation import ClosedLoop  # noqa: E402

KEYS = ("alpha", "h_c", "J", "mu_t", "mu_y", "prediction_error")


def run(params: dict[str, float], seed: int = 0) -> tuple[pd.DataFrame, dict[str, float]]:
    """Closed loop on paper004_urban; the run's DataFrame with the DMC's info columns."""
    sc = get_scenario("paper004_urban")
    ctrl = DMCController(**params)
    loop = ClosedLoop(sc, ctrl)
    loop.reset(seed=seed)
    cols: dict[str, list[float]] = {k: [] for k in KEYS}
    while not loop.done:
        info = loop.step()
        for k in KEYS:
            cols[k].append(float(info[k]))
    res = loop.result()
    df = res.df.iloc[: len(cols["alpha"])].copy()
    for k in KEYS:
        df[k] = cols[k]
    return df, res.metrics | ctrl.get_params()


def plot(df: pd.DataFrame, info: dict[str, float], out: str) -> None:
    t = df["t_s"].to_numpy()
    fig, axes = plt.subplots(5, 1, figsize=(11, 12), sharex=True,
                             gridspec_kw={"height_ratios": [2.0, 1, 1, 1, 1]})
    a0, ae, ax = axes[0], axes[1], axes[2:]
    a0.plot(t, 3.6 * df["v_ref_mps"], color="0.55", lw=2.5, label="reference $v_{ref}$")
    a0.plot(t, 3.6 * df["v_mps"], color="C0", lw=1.2, label="speed $v$ (DMC)")
    a0.set_ylabel("speed [km/h]")
    a0.set_title(
        "paper004_urban, DMC (N=60, P=L=15): "
        f"stop error {info['stop_error_m']:+.3f} m, time error {info['time_error_s']:.1f} s, "
        f"E_v {info['E_v_mps']:.4f} m/s"
    )
    a0.legend(loc="lower center")

    ae.plot(t, df["v_ref_mps"] - df["v_mps"], color="C0", lw=0.9)
    ae.set_ylabel("$v_{ref} - v$ [m/s]")
    ae.set_ylim(-0.12, 0.12)  # the start (up to 0.5 m/s) is clipped
    g = ae.twinx()
    g.fill_between(t, df["gradient_permil"], color="C2", alpha=0.15, step="post")
    g.set_ylabel("gradient [‰]", color="C2")
    g.tick_params(axis="y", colors="C2")
    ae.set_zorder(g.get_zorder() + 1)
    ae.patch.set_visible(False)

    ax[0].plot(t, df["alpha"], color="C1", lw=1.0, drawstyle="steps-post")
    bounds = ((info["alpha_min"], r"$\alpha_{min}$"), (info["alpha_max"], r"$\alpha_{max}$"))
    for val, name in bounds:
        ax[0].axhline(val, color="0.4", ls="--", lw=0.8)
        ax[0].text(t[-1], val, " " + name, va="center", fontsize=9)
    ax[0].set_ylabel(r"softening $\alpha$")

    ax[1].plot(t, df["h_c"], color="C3", lw=1.0, drawstyle="steps-post")
    ax[1].axhline(info["h0"], color="0.4", ls="--", lw=0.8)
    ax[1].text(t[-1], info["h0"], r" $h_0$", va="center", fontsize=9)
    ax[1].set_ylabel("correction $h_c$")

    ax[2].plot(t, df["mu_t"], color="C4", lw=0.8, alpha=0.6, label=r"$\mu_t$ (response time)")
    ax[2].plot(t, df["mu_y"], color="C2", lw=0.8, alpha=0.6, label=r"$\mu_y$ (predicted outputs)")
    ax[2].plot(t, df["J"], color="k", lw=1.0, drawstyle="steps-post", label=r"$J=\min$")
    ax[2].set_ylabel("satisfaction $J$")
    ax[2].set_ylim(-0.05, 1.05)
    ax[2].legend(loc="lower left", fontsize=8, ncol=3)
    ax[2].set_xlabel("time [s]")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="path of the PNG to write")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="DMC tunable parameter (repeatable)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    params = {}
    for item in args.param:
        name, _, value = item.partition("=")
        params[name.strip()] = float(value)
    df, info = run(params, args.seed)
    plot(df, info, args.out)
    keys = ("stop_error_m", "time_error_s", "E_v_mps", "ITAE_m_s",
            "comfort_mean_abs_jerk_mps3", "energy_kWh")
    print(", ".join(f"{k} {info[k]:.4g}" for k in keys))
    print(
        f"alpha in [{df['alpha'].min():.3f}, {df['alpha'].max():.3f}], "
        f"h_c in [{df['h_c'].min():.3f}, {df['h_c'].max():.3f}], "
        f"J mean {df['J'].mean():.3f}; figure: {args.out}"
    )


if __name__ == "__main__":
    main()
