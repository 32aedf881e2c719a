"""The `lwm` dispatcher: documented options, dataclass options, plugin commands, errors, re-exec."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib.util
import os
import subprocess
import sys
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from lwm_models.cli import main as cli_main
from lwm_models.cli import play
from lwm_models.cli.args import LwmParser, add_dataclass_arguments
from lwm_models.errors import LwmError

ROOT = Path(__file__).resolve().parents[1]
SETUP_PY = ROOT / "ros_ws" / "src" / "lwm_nodes" / "setup.py"
HAS_LWM_NODES = importlib.util.find_spec("lwm_nodes") is not None


class FakeEntryPoint:
    """What main reads of an importlib.metadata.EntryPoint: name, value, load()."""

    def __init__(self, name: str, load) -> None:
        self.name, self.value, self._load = name, f"fake.{name}:register", load

    def load(self):
        return self._load()


def _parsers(parser: argparse.ArgumentParser):
    """The parser and every subparser under it, with their deferred options added."""
    if isinstance(parser, LwmParser):
        parser.add_deferred_arguments()
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases map to the same parser
                yield from _parsers(sub)


def _normalized(text: str) -> str:
    return " ".join(text.split())


# --------------------------------------------------------------------------- --help
def test_every_option_of_every_command_has_help():
    plugins = []
    if HAS_LWM_NODES:
        plugins.append(EntryPoint(name="ros", value="lwm_nodes.ros_cli:register", group=cli_main.PLUGIN_GROUP))
    parser = cli_main.build_parser(plugins)
    seen = 0
    for p in _parsers(parser):
        p.format_help()  # every help string formats (a stray % would raise here)
        for action in p._actions:
            if not action.option_strings or isinstance(action, argparse._HelpAction):
                continue
            seen += 1
            assert action.help and action.help != argparse.SUPPRESS, f"{p.prog} {action.option_strings[0]}"
    assert seen > 80  # every command's options were walked, the deferred train and table3 ones too


def test_train_help_is_the_dataclass_documentation_with_defaults():
    from lwm_models.world.train import TrainArgs

    parser = cli_main.build_parser([])
    (train,) = [p for p in _parsers(parser) if p.prog == "lwm train"]
    text = _normalized(train.format_help())
    for f in dataclasses.fields(TrainArgs):
        assert _normalized(f.metadata["help"]) in text, f.name
    assert "--steps N optimizer steps in total (a resumed run continues to this) (default: 100000)" in text
    assert "--cosine, --no-cosine cosine decay to 10% of lr" in text and "(default: --no-cosine)" in text
    assert "--cpu-budget-minutes X" in text and "--max-minutes X" in text
    assert "--preset {paper,small,tiny}" in text


def test_table3_budget_options_come_from_budget():
    from lwm_models.agent.learning import Budget

    parser = cli_main.build_parser([])
    args = parser.parse_args(["agent", "table3", "--data", ".", "--iterations", "3", "--overlap"])
    assert (args.iterations, args.episodes, args.overlap) == (3, Budget().episodes, True)
    (table3,) = [p for p in _parsers(parser) if p.prog == "lwm agent table3"]
    text = _normalized(table3.format_help())
    budget_help = {f.name: f.metadata["help"] for f in dataclasses.fields(Budget)}
    assert _normalized(budget_help["plans_per_start"]) + " (default: 8)" in text


# --------------------------------------------------------------------------- dataclass options
@dataclass
class Options:
    name: str = field(metadata={"help": "a required name"})
    count: int = field(default=3, metadata={"help": "how many"})
    limit: int | None = field(default=None, metadata={"help": "at most this many (default: no limit)"})
    rate: float | None = field(default=None, metadata={"help": "a rate in %"})
    scale: float = field(default=0.5, metadata={"help": "a scale"})
    verbose: bool = field(default=False, metadata={"help": "talk more"})
    color: bool = field(default=True, metadata={"help": "use colours"})


def _options_parser(**kwargs) -> LwmParser:
    parser = LwmParser(prog="t")
    add_dataclass_arguments(parser, Options, **kwargs)
    return parser


def test_dataclass_options_take_exact_types():
    args = _options_parser().parse_args(
        ["--name", "x", "--count", "7", "--limit", "2", "--rate", "0.25", "--verbose", "--no-color"]
    )
    built = Options(**vars(args))
    assert built == Options(name="x", count=7, limit=2, rate=0.25, scale=0.5, verbose=True, color=False)
    assert type(built.count) is int and type(built.limit) is int and type(built.rate) is float
    assert Options(**vars(_options_parser().parse_args(["--name", "y"]))) == Options(name="y")


def test_dataclass_options_reject_bad_values_and_missing_required(capsys):
    for argv in (["--count", "3"], ["--name", "x", "--count", "2.5"], ["--name", "x", "--limit", "many"]):
        with pytest.raises(SystemExit) as exc:
            _options_parser().parse_args(argv)
        assert exc.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "t: error: the following arguments are required: --name"
    assert err[1] == "t: error: argument --count: invalid int value: '2.5'"
    assert len(err) == 3  # one line per error, no usage block


def test_dataclass_options_help_and_extra():
    parser = _options_parser(only=["count", "rate", "color"], extra={"count": {"choices": [1, 2, 3]}})
    text = _normalized(parser.format_help())
    assert "--count {1,2,3} how many (default: 3)" in text
    assert "--rate X a rate in %" in text and "--color, --no-color use colours (default: --color)" in text
    assert "--name" not in text and "--verbose" not in text


def test_dataclass_options_refuse_undocumented_or_unsupported_fields():
    @dataclass
    class Undocumented:
        n: int = 1

    @dataclass
    class Listy:
        xs: list[int] = field(default_factory=list, metadata={"help": "numbers"})

    with pytest.raises(TypeError, match="no metadata"):
        add_dataclass_arguments(LwmParser(), Undocumented)
    with pytest.raises(TypeError, match="no option for the type"):
        add_dataclass_arguments(LwmParser(), Listy)
    with pytest.raises(TypeError, match="no field"):
        add_dataclass_arguments(LwmParser(), Options, extra={"nmae": {}})


def test_train_arguments_build_train_args(tmp_path):
    from lwm_models.world.train import TrainArgs

    argv = ["train", "--data", str(tmp_path), "--out", "r", "--no-progress", "--eval-episodes", "5"]
    args = cli_main.build_parser([]).parse_args(argv + ["--attn-dropout", "0", "--kind", "oracle"])
    built = TrainArgs(**{f.name: getattr(args, f.name) for f in dataclasses.fields(TrainArgs)})
    assert built == TrainArgs(
        data=str(tmp_path), out="r", progress=False, eval_episodes=5, attn_dropout=0.0, kind="oracle"
    )
    assert args.func.__module__ == "lwm_models.cli.train"


# --------------------------------------------------------------------------- commands
def test_play_is_an_ordinary_subcommand():
    args = cli_main.build_parser([]).parse_args(["play", "--split", "train", "--start", "none", "--texts"])
    assert args.func is play.run and args.split == "train" and args.start is None and args.texts == []


def _hello_plugin(calls: list):
    def register(subparsers):
        p = subparsers.add_parser("hello", help="say hello")
        p.add_argument("--times", type=int, default=1, help="how often")
        p.set_defaults(func=lambda args: calls.append(args.times) or 0)

    return register


def test_plugins_from_entry_points_become_commands(monkeypatch):
    calls: list = []
    points = [FakeEntryPoint("hello", lambda: _hello_plugin(calls))]
    monkeypatch.setattr(cli_main, "entry_points", lambda group: points if group == cli_main.PLUGIN_GROUP else [])
    assert cli_main.main(["hello", "--times", "3"]) == 0
    assert calls == [3]


def test_a_plugin_cannot_replace_a_core_command(monkeypatch):
    calls: list = []

    def register(subparsers):
        subparsers.add_parser("train").set_defaults(func=lambda args: calls.append(args) or 0)

    monkeypatch.setattr(cli_main, "entry_points", lambda group: [FakeEntryPoint("train", lambda: register)])
    args = cli_main.build_parser().parse_args(["train", "--data", ".", "--out", "r"])
    assert args.func.__module__ == "lwm_models.cli.train" and not calls


def test_ros_without_its_package_is_a_one_line_hint(monkeypatch, capsys):
    monkeypatch.setattr(cli_main, "entry_points", lambda group: [])
    assert cli_main.main(["ros", "echo", "/lwm/status", "--latched", "--count", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lwm ros: error: the ROS 2 nodes are not installed")
    assert err[0].endswith("run ./run_nodes.sh once")


def test_a_plugin_that_fails_to_load_leaves_a_hint_and_the_other_commands(monkeypatch, capsys):
    def broken():
        raise ImportError("No module named 'rclpy'")

    monkeypatch.setattr(cli_main, "entry_points", lambda group: [FakeEntryPoint("ros", broken)])
    assert cli_main.main(["ros", "nodes"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "lwm ros: error: the ROS 2 nodes are not installed (No module named 'rclpy'); run ./run_nodes.sh once"
    assert cli_main.main(["ledger", "show", "--path", "/nonexistent/ledger.sqlite"]) == 2
    assert capsys.readouterr().err.strip() == "lwm: error: no ledger at /nonexistent/ledger.sqlite"


@pytest.mark.skipif(not HAS_LWM_NODES, reason="lwm_nodes is not installed")
def test_the_ros_entry_point_registers_lwm_ros_without_importing_rclpy():
    point = EntryPoint(name="ros", value="lwm_nodes.ros_cli:register", group=cli_main.PLUGIN_GROUP)
    args = cli_main.build_parser([point]).parse_args(["ros", "call", "/lwm/imagine", "{}", "--timeout", "5"])
    assert args.func.__module__ == "lwm_nodes.ros_cli" and args.func.__name__ == "run"
    assert (args.cmd, args.service, args.payload, args.timeout) == ("call", "/lwm/imagine", "{}", 5.0)
    # `lwm` loads every plugin on every run: the ros command's module must be cheap to import.
    code = "import sys, lwm_nodes.ros_cli; print('rclpy' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "False", proc.stderr


def _setup_entry_points() -> dict[str, list[str]]:
    tree = ast.parse(SETUP_PY.read_text())
    (call,) = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup"]
    (points,) = [k.value for k in call.keywords if k.arg == "entry_points"]
    return ast.literal_eval(points)


def test_lwm_nodes_setup_declares_the_ros_command_and_every_node():
    points = _setup_entry_points()
    assert points[cli_main.PLUGIN_GROUP] == ["ros = lwm_nodes.ros_cli:register"]
    nodes = ROOT / "ros_ws" / "src" / "lwm_nodes" / "lwm_nodes"
    scripts = dict(line.replace(" ", "").split("=") for line in points["console_scripts"])
    assert set(scripts) == {
        f"lwm_{n}_node" for n in ("env", "world_model", "planner", "human", "recorder", "fleet_page", "live_view")
    }
    for target in scripts.values():
        module, function = target.split(":")
        source = (nodes / f"{module.split('.')[-1]}.py").read_text()
        assert f"\ndef {function}(" in source, target


# --------------------------------------------------------------------------- errors and re-exec
def _failing_plugin(exc: BaseException):
    def register(subparsers):
        def fail(args):
            raise exc

        subparsers.add_parser("fail").set_defaults(func=fail)

    return register


@pytest.mark.parametrize(
    "exc, status, message",
    [
        (LwmError("the input is wrong"), 2, "lwm: error: the input is wrong"),
        (FileNotFoundError(2, "No such file or directory", "x.json"), 2, "lwm: error: [Errno 2]"),
        (KeyboardInterrupt(), 130, ""),
    ],
)
def test_errors_of_handlers(monkeypatch, capsys, exc, status, message):
    monkeypatch.setattr(cli_main, "entry_points", lambda group: [FakeEntryPoint("fail", lambda: _failing_plugin(exc))])
    assert cli_main.main(["fail"]) == status
    err = capsys.readouterr().err
    assert err.startswith(message) and len(err.splitlines()) == (1 if message else 0)


def test_a_bug_still_shows_its_traceback(monkeypatch):
    monkeypatch.setattr(
        cli_main, "entry_points", lambda group: [FakeEntryPoint("fail", lambda: _failing_plugin(ZeroDivisionError()))]
    )
    with pytest.raises(ZeroDivisionError):
        cli_main.main(["fail"])


class Reexec(Exception):
    pass


def test_train_reexecutes_itself_with_the_allocator_tunables(monkeypatch, tmp_path):
    calls = []

    def execve(path, argv, env):
        calls.append((path, argv, env))
        raise Reexec

    monkeypatch.setattr(os, "execve", execve)
    for name in ("WORLD_SIZE", "LWM_NO_ALLOCATOR_TUNING", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    argv = ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--preset", "tiny"]
    with pytest.raises(Reexec):
        cli_main.main(argv)
    ((path, new_argv, env),) = calls
    assert path == sys.executable and new_argv == [sys.executable, "-m", "lwm_models.cli.main", *argv]
    assert env["GLIBC_TUNABLES"] == cli_main.ALLOCATOR_TUNABLES
    assert cli_main.main(["train", "--data", str(tmp_path), "--out", "r", "--preset", "huge"]) == 2
    assert len(calls) == 1  # a bad command line fails before the re-exec
