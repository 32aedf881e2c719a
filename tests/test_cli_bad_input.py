"""Bad input to every `lwm` subcommand: exit status 2 and one line on stderr naming the problem.

Each case runs the installed console script as a user would. The cases run in parallel threads
from one fixture (most of the time is spent importing torch in the child processes), and each
case is then checked, and reported, on its own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from lwm_models.ledger import Ledger
from lwm_models.world.shipped import SHIPPED

_SCRIPT = Path(sys.executable).with_name("lwm")
LWM = [str(_SCRIPT)] if _SCRIPT.is_file() else [sys.executable, "-m", "lwm_models.cli.main"]

# (id, argv, a part of the message). In argv, {tmp} is the fixture's directory, where
# empty/ is an existing directory that is neither a dataset nor a checkpoint, and badconfig/ a
# checkpoint directory whose config.json is not JSON (it passes the checks made before torch loads).
CASES: list[tuple[str, list[str], str]] = [
    ("no command", [], "the following arguments are required: COMMAND"),
    ("unknown command", ["bogus"], "invalid choice: 'bogus'"),
    ("unknown option", ["data", "splits", "--bogus"], "unrecognized arguments: --bogus"),
    # data
    ("splits negative seed", ["data", "splits", "--seed", "-1"], "argument --seed: must be >= 0, got -1"),
    ("splits out under a file", ["data", "splits", "--out", "{tmp}/malformed.json/s.json"], "malformed.json"),
    ("generate zero episodes", ["data", "generate", "--out", "{tmp}/d", "--episodes-per-game", "0"], "must be >= 1"),
    ("generate typo rate", ["data", "generate", "--out", "{tmp}/d", "--typo-rate", "1.5"], "must be in [0, 1]"),
    (
        "generate malformed texts",
        ["data", "generate", "--out", "{tmp}/d", "--text-source", "{tmp}/malformed.json"],
        "malformed.json: not valid JSON",
    ),
    # play
    ("play bad split", ["play", "--split", "nonsense"], "argument --split: invalid choice: 'nonsense'"),
    ("play index out of range", ["play", "--index", "100000"], "--index must be in 0.."),
    ("play start out of range", ["play", "--start", "24"], "argument --start: expected 0-23"),
    ("play texts of the wrong shape", ["play", "--texts", "{tmp}/wrongshape.json"], "must be a JSON object"),
    # train
    (
        "train unknown preset",
        ["train", "--data", "{tmp}/empty", "--out", "{tmp}/run", "--preset", "foo"],
        "argument --preset: invalid choice: 'foo'",
    ),
    (
        "train unknown kind",
        ["train", "--data", "{tmp}/empty", "--out", "{tmp}/run", "--kind", "foo"],
        "argument --kind: invalid choice: 'foo'",
    ),
    ("train missing data", ["train", "--data", "{tmp}/missing", "--out", "{tmp}/run"], "no such directory"),
    (
        "train on a directory that is no dataset",
        ["train", "--data", "{tmp}/empty", "--out", "{tmp}/run", "--kind", "oracle", "--preset", "tiny"],
        "is not a Messenger-WM dataset",
    ),
    # tune-reader
    (
        "tune-reader missing checkpoint",
        ["tune-reader", "--init", "{tmp}/missing", "--data", "{tmp}/empty", "--out", "{tmp}/run"],
        "no such directory",
    ),
    (
        "tune-reader token drop out of range",
        ["tune-reader", "--init", "{tmp}/empty", "--data", "{tmp}/empty", "--out", "{tmp}/run", "--token-drop", "2"],
        "must be in [0, 1]",
    ),
    # eval
    ("eval not a checkpoint", ["eval", "--checkpoint", "{tmp}/empty", "--data", "{tmp}/empty"], "not a checkpoint"),
    (
        "eval malformed config.json",
        ["eval", "--checkpoint", "{tmp}/badconfig", "--data", "{tmp}/empty"],
        "config.json is not valid JSON",
    ),
    ("eval missing data", ["eval", "--checkpoint", "{tmp}/badconfig", "--data", "{tmp}/missing"], "no such directory"),
    (
        "eval bad split",
        ["eval", "--checkpoint", "{tmp}/badconfig", "--data", "{tmp}/empty", "--splits", "newall-test", "tset"],
        "invalid choice: 'tset'",
    ),
    (
        "eval negative episodes",
        ["eval", "--checkpoint", "{tmp}/badconfig", "--data", "{tmp}/empty", "--imagination-episodes", "-1"],
        "must be >= 0",
    ),
    # imagine
    ("imagine non-numeric actions", ["imagine", "--actions", "3,x,1"], "argument --actions: expected comma-separated"),
    ("imagine action out of range", ["imagine", "--actions", "3,7"], "actions are 0-4, got 7"),
    ("imagine zero trajectories", ["imagine", "--n", "0"], "argument --n: must be >= 1"),
    ("imagine index out of range", ["imagine", "--index", "99999"], "--index must be in 0.."),
    ("imagine not a checkpoint", ["imagine", "--checkpoint", "{tmp}/empty"], "not a checkpoint"),
    # export
    ("export missing checkpoint", ["export", "--checkpoint", "{tmp}/missing", "--out", "{tmp}/x"], "not a checkpoint"),
    # parser-accuracy
    ("parser-accuracy missing file", ["parser-accuracy", "--texts", "{tmp}/missing.json"], "no such description"),
    ("parser-accuracy malformed JSON", ["parser-accuracy", "--texts", "{tmp}/malformed.json"], "not valid JSON"),
    # agent
    (
        "pretrain missing data",
        ["agent", "pretrain", "--data", "{tmp}/missing", "--out", "{tmp}/p"],
        "no such directory",
    ),
    (
        "pretrain negative steps",
        ["agent", "pretrain", "--data", "{tmp}/empty", "--out", "{tmp}/p", "--steps", "-1"],
        "argument --steps: must be >= 1",
    ),
    (
        "table3 model without checkpoint",
        ["agent", "table3", "--data", "{tmp}/empty", "--models", "emma"],
        "CHECKPOINT pairs, got 'emma'",
    ),
    (
        "table3 malformed records",
        ["agent", "table3", "--data", "{tmp}/empty", "--from-records", "{tmp}/malformed.json"],
        "malformed.json:1: not a JSON record",
    ),
    (
        "table3 records that are not Table 3's",
        ["agent", "table3", "--data", "{tmp}/empty", "--from-records", "{tmp}/wrongshape.json"],
        "wrongshape.json:1: not a Table 3 record",
    ),
    (
        "table3 resumed under another budget",
        ["agent", "table3", "--data", "{tmp}/empty", "--records", "{tmp}/constrained.jsonl", "--iterations", "3"],
        "holds records of another budget (constrained, iterations); use another --records",
    ),
    (
        "table3 resumed with another checkpoint",
        [
            "agent",
            "table3",
            "--data",
            "{tmp}/empty",
            "--records",
            "{tmp}/old_emma.jsonl",
            "--models",
            f"emma={SHIPPED['emma']}",
        ],
        "holds records of emma from another checkpoint (0123456789ab); use another --records",
    ),
    # ledger
    ("ledger missing", ["ledger", "show", "--path", "{tmp}/missing.sqlite"], "no ledger at"),
    ("ledger not a database", ["ledger", "show", "--path", "{tmp}/malformed.json"], "is not a ledger"),
    ("ledger unknown review", ["ledger", "show", "--path", "{tmp}/ledger.sqlite", "--review", "r9"], "no review 'r9'"),
    # ros: with lwm_nodes installed argparse rejects the subcommand; without, the hint says what to install
    ("ros unknown subcommand", ["ros", "bogus"], "lwm ros: error:"),
    # a file that is not a key file: refused in one line, never overwritten
    ("ros keys not a key file", ["ros", "keys", "--keys-file", "{tmp}/malformed.json"], "malformed.json: not JSON"),
]


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, subprocess.CompletedProcess]:
    tmp = tmp_path_factory.mktemp("bad_input")
    (tmp / "empty").mkdir()
    (tmp / "badconfig").mkdir()
    (tmp / "badconfig" / "config.json").write_text("{not json")
    (tmp / "malformed.json").write_text("{not json\n" + "x" * 1000)
    (tmp / "wrongshape.json").write_text("[1, 2, 3]\n")
    record = {"setting": "online_il", "model": "emma", "split": "newall-test", "game": 0, "return": 1.0}
    record.update(learn_seconds=1.0, budget={"constrained": True})
    (tmp / "constrained.jsonl").write_text(json.dumps(record) + "\n")
    old = {**record, "budget": {}, "checkpoint": "0123456789abcdef"}  # the shipped EMMA-LWM before a re-ship
    (tmp / "old_emma.jsonl").write_text(json.dumps(old) + "\n")
    Ledger(tmp / "ledger.sqlite").record("r1", "plan", {"plan_id": "p1"})

    def run(argv: list[str]) -> subprocess.CompletedProcess:
        argv = [a.replace("{tmp}", str(tmp)) for a in argv]
        return subprocess.run(
            LWM + argv, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, env=os.environ.copy()
        )

    with ThreadPoolExecutor(max_workers=4) as pool:
        done = pool.map(run, [argv for _, argv, _ in CASES])
        return {name: proc for (name, _, _), proc in zip(CASES, done, strict=True)}


@pytest.mark.parametrize("name, argv, message", CASES, ids=[name for name, _, _ in CASES])
def test_bad_input_is_one_line_and_status_2(results, name: str, argv: list[str], message: str) -> None:
    proc = results[name]
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("lwm"), lines[0]
    assert message in lines[0], lines[0]
