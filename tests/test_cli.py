"""The CLI as a user drives it: help, resolved config, exit codes, sweeps."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosmos_lite.cli", *args], capture_output=True, text=True)


def test_help_lists_subcommands():
    r = cli("--help")
    assert r.returncode == 0
    assert "probe" in r.stdout and "train" in r.stdout


def test_sub_help_and_cfg_job():
    r = cli("probe", "--help")
    assert r.returncode == 0 and "input:" in r.stdout
    r = cli("probe", "input=a.mp4", "--cfg", "job")
    assert r.returncode == 0 and "input: a.mp4" in r.stdout


def test_unknown_key_is_exit_2_and_named():
    r = cli("probe", "inptu=a.mp4")
    assert r.returncode == 2
    assert "inptu" in r.stderr


def test_unknown_subcommand_is_exit_2():
    assert cli("frobnicate").returncode == 2


def test_probe_ok_and_unreadable_input(sintel_10s, tmp_path):
    r = cli("probe", f"input={sintel_10s}")
    assert r.returncode == 0
    assert json.loads(r.stdout)["num_frames"] == 240
    bad = tmp_path / "bad.mp4"
    bad.write_text("nope")
    r = cli("probe", f"input={bad}")
    assert r.returncode == 4 and str(bad) in r.stderr


def test_multirun_runs_each_value(sintel_10s):
    r = cli("probe", "-m", f"input={sintel_10s},{sintel_10s}")
    assert r.returncode == 0
    *results, summary = r.stdout.strip().splitlines()
    assert len(results) == 2
    assert [job["exit"] for job in json.loads(summary)["multirun"]] == [0, 0]


@pytest.mark.parametrize("args", [["train"], ["train", "experiment=does_not_exist"]])
def test_train_needs_a_known_experiment(args):
    assert cli(*args).returncode == 2
