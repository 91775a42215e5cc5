"""The ``train-envs`` command: subcommands found through entry points, errors as one line."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from train_envs import cli, cli_args
from train_envs.reproduce import get_reproduction, list_reproductions

ROOT = Path(__file__).resolve().parents[2]


def _subcommands(parser: argparse.ArgumentParser) -> list[str]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return list(action.choices)


def test_the_packages_above_register_their_commands():
    assert set(cli_args.registered(cli_args.CLI_GROUP)) >= {"tuners", "agents"}
    assert _subcommands(cli.build_parser()) == [
        "list",
        "train",
        "evaluate",
        "tune",
        "benchmark",
        "reproduce",
        "simulate",
    ]


def test_importing_the_cli_imports_no_layer_above():
    code = (
        "import sys, train_envs.cli, train_envs.reproduce, train_envs.reproduce.paper004\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('tuners', 'agents')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"


def test_a_registered_command_is_added_and_a_broken_one_skipped(monkeypatch, capsys):
    class EP:
        def __init__(self, name, target):
            self.name, self._target = name, target

        def load(self):
            if isinstance(self._target, Exception):
                raise self._target
            return self._target

    def add_hello(sub):
        sub.add_parser("hello").set_defaults(func=lambda args: print("hi") or 0)

    fake = {"a": EP("a", add_hello), "b": EP("b", ImportError("no module named x"))}
    monkeypatch.setattr(cli, "registered", lambda group: fake)
    assert cli.main(["hello"]) == 0
    out, err = capsys.readouterr()
    assert out == "hi\n" and err.strip() == (
        "warning: train-envs: commands of 'b' unavailable (no module named x)"
    )


def test_paper004_reproduction_lives_with_the_tuners():
    from train_envs.reproduce import paper004
    from tuners.paper004 import reproduce_paper004

    assert list_reproductions() == [f"paper00{i}" for i in range(5)]
    assert get_reproduction("paper004") is reproduce_paper004
    assert paper004.reproduce_paper004 is reproduce_paper004  # its import path works
    with pytest.raises(ValueError, match="no reproduction for 'nope'; choose one of: paper000"):
        get_reproduction("nope")
    with pytest.raises(AttributeError):
        paper004.nope  # noqa: B018


def test_bad_input_is_one_line_and_exit_code_2(capsys):
    assert cli.main(["simulate", "--param", "kp=abc"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --param kp:") and err.count("\n") == 1
    assert cli.main(["tune"]) == 2
    assert capsys.readouterr().err.startswith("error: tune needs --env (or --resume")
    with pytest.raises(SystemExit) as exc:
        cli.main(["reproduce", "nope"])
    assert exc.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err.splitlines()[-1]


@pytest.mark.parametrize("module", ["train_envs.cli", "tuners.cli", "agents.cli"])
def test_each_cli_module_is_the_train_envs_command(module):
    out = subprocess.run(
        [sys.executable, "-m", module, "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "{list,train,evaluate,tune,benchmark,reproduce,simulate}" in out


def test_seeds_parse_and_bad_ones_name_the_flag():
    assert cli_args.parse_seeds(["0", "2-4", "7,9"]) == [0, 2, 3, 4, 7, 9]
    assert cli_args.parse_seeds(None) is None
    for bad, msg in (("5-1", "range '5-1' is empty"), ("x", "'x' is not an integer"),
                     ("-2", "seeds are integers >= 0"), (",", "no seed given")):  # fmt: skip
        with pytest.raises(ValueError, match=f"--holdout-seeds: {msg}"):
            cli_args.parse_seeds([bad], "--holdout-seeds")


def test_errors_of_any_type_are_one_line():
    assert cli.error_line(ValueError("bad\n  input")) == "error: bad input"
    assert cli.error_line(KeyError("no study 'x'")) == "error: no study 'x'"
    assert cli.error_line(OSError("disk full")) == "error: OSError: disk full"
