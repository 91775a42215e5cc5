"""Importing the plotting modules leaves matplotlib's backend alone (Jupyter's inline
backend, a user's GUI backend), and their figures draw without pyplot."""

import subprocess
import sys

_CHECK = """
import matplotlib
matplotlib.use("svg")
import train_envs, train_envs.plotting, train_envs.plots_papers, tuners.plots, agents
from train_envs.plotting import new_figure
fig, ax = new_figure((3, 2), 1, 1)
ax.plot([0, 1], [1, 0])
import io
fig.savefig(io.BytesIO(), format="png")
print(matplotlib.get_backend())
"""


def test_imports_keep_the_backend():
    out = subprocess.run(
        [sys.executable, "-c", _CHECK], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out[-1] == "svg"
