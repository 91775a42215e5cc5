"""``train-envs reproduce <paper> --out DIR``: the table as CSV, the figures, progress."""

from __future__ import annotations

import pandas as pd
import pytest
from matplotlib.figure import Figure

from train_envs import cli
from train_envs.reproduce import get_figures, paper000, paper002


def test_out_writes_the_table_and_the_figures_from_the_same_runs(tmp_path, monkeypatch, capsys):
    small = {k: v for k, v in paper000.PAPER000.items() if k[0] == "paper000_single_section"}
    small.pop(("paper000_single_section", "afsmc"))
    monkeypatch.setattr(paper000, "PAPER000", small)
    assert cli.main(["reproduce", "paper000", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    table = pd.read_csv(tmp_path / "paper000.csv")
    assert list(table["controller"]) == ["sempc", "mpc000", "afsmc000"]
    for name in ("compare_single_section", "cars_single_section_sempc"):
        assert (tmp_path / f"paper000_{name}.png").stat().st_size > 10_000
        assert f"paper000_{name}.png" in out
    assert "e-1" not in out  # no round-off noise printed for zeros


@pytest.mark.parametrize("paper", ["paper000", "paper001", "paper002", "paper003", "paper004"])
def test_every_reproduction_has_figures(paper):
    assert callable(get_figures(paper))


def test_paper002_progress_and_traces_for_its_figures(capsys):
    traces: dict[str, pd.DataFrame] = {}
    paper002.compare_paper002((0,), t_max_s=10.0, workers=1, traces=traces, progress=True)
    err = capsys.readouterr().err
    assert err.count("paper002 (paper002_cruise):") == len(paper002.CONTROLLERS)
    assert set(traces) == set(paper002.CONTROLLERS)
    runs = {f"paper002_cruise/{c}": df for c, df in traces.items()}
    figs = paper002.figures_paper002(pd.DataFrame(), runs)
    assert set(figs) == {"cruise"} and isinstance(figs["cruise"], Figure)
