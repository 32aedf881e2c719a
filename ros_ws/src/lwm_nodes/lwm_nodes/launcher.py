"""The system's launcher (there is no `ros2 launch` from PyPI): a small supervisor.

It starts each node as its own process, waits until each prints READY, prefixes and stores every
node's output (logs/<node>.log), forwards SIGINT/SIGTERM to the nodes, restarts a node that dies
(up to --max-restarts), and reports each node's exit code at the end.

Before the nodes start, it makes sure the reviewers' key file exists (--keys-file, default
LOG_DIR/reviewer_keys.json; created with random keys, mode 0600, if missing) and gives its path to
the nodes that sign (the human node) or verify (the world-model server and the planner).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from lwm_models import run_dirs, signing
from lwm_models.ledger import Ledger
from lwm_nodes.common import ros_environment


@dataclass
class NodeSpec:
    name: str
    module: str
    params: dict[str, str] = field(default_factory=dict)
    interactive: bool = False  # inherits the terminal (its output is not prefixed or stored)
    final: bool = False  # when it exits with 0, the whole system stops (the scripted human)
    first: bool = False  # ready before the others start, stopped after they exit (the recorder)
    namespace: str = ""  # a fleet's agent: its nodes' relative names resolve under /<namespace>
    config: Path | None = None  # its parameters' YAML file; `params` override it

    def command(self) -> list[str]:
        cmd = [sys.executable, "-m", self.module]
        if self.params or self.namespace or self.config:
            cmd.append("--ros-args")
            if self.namespace:
                cmd += ["-r", f"__ns:=/{self.namespace}"]
            if self.config is not None:
                cmd += ["--params-file", str(self.config)]  # first: a later -p wins over the file
            for k, v in self.params.items():
                cmd += ["-p", f"{k}:={v}"]
        return cmd

    @property
    def role(self) -> str:
        """What the node is (env, world_model, planner, human, recorder), whichever agent it serves."""
        return self.name.rpartition("/")[2]


class Supervised:
    def __init__(self, spec: NodeSpec, log_dir: Path, echo: bool) -> None:
        self.spec = spec
        self.log_path = log_dir / f"{spec.name.replace('/', '.')}.log"
        self.echo = echo
        self.ready = threading.Event()
        self.restarts = 0
        self.proc: subprocess.Popen | None = None
        self.exit_codes: list[int] = []

    def start(self) -> None:
        self.ready.clear()
        if self.spec.interactive:
            self.proc = subprocess.Popen(self.spec.command())
            self.ready.set()
            return
        self.proc = subprocess.Popen(
            self.spec.command(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            start_new_session=True,  # our signal handler forwards; a terminal's ^C must not hit twice
        )
        threading.Thread(target=self._pump, args=(self.proc,), daemon=True).start()

    def _pump(self, proc: subprocess.Popen) -> None:
        with open(self.log_path, "a") as log:
            for line in proc.stdout:
                stamped = f"[{self.spec.name}] {line.rstrip()}"
                log.write(f"{time.strftime('%H:%M:%S')} {stamped}\n")
                log.flush()
                if line.startswith("READY"):
                    self.ready.set()
                if self.echo or line.startswith(("SUMMARY", "PAGE", "FOXGLOVE")):  # the outcome and the addresses
                    print(stamped, flush=True)

    def signal(self, sig: int) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(sig)


CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
# Each node's parameters, commented, in a YAML file of its own (passed with --params-file); the
# launcher adds only what its command line was given and the run's paths.
CONFIG_FILES = {
    "env": "messenger_env.yaml",
    "world_model": "lwm_world_model.yaml",
    "planner": "planner.yaml",
    "human": "human_feedback.yaml",
    "recorder": "lwm_recorder.yaml",
    "fleet_page": "fleet_page.yaml",
    "live_view": "live_view.yaml",
}


def config_value(config_dir: Path, role: str, key: str):
    """A parameter's value in a node's YAML file (None when the file does not set it)."""
    import yaml

    loaded = yaml.safe_load((config_dir / CONFIG_FILES[role]).read_text()) or {}
    return loaded.get("/**", {}).get("ros__parameters", {}).get(key)


def default_nodes(
    human: str, given: dict[str, dict[str, str]] | None = None, config_dir: Path = CONFIG_DIR
) -> list[NodeSpec]:
    """The system's nodes, each with its YAML file from config_dir and the parameters `given` per
    node (env, world_model, planner, human), which override the file's. human: 'scripted',
    'interactive', 'page' (the browser; give it page_port) or 'none'. The planner loads no world
    model: only the world-model server gets the checkpoint."""
    given = given or {}

    def spec(role: str, module: str, **extra) -> NodeSpec:
        return NodeSpec(role, module, dict(given.get(role, {})), config=config_dir / CONFIG_FILES[role], **extra)

    nodes = [
        spec("env", "lwm_nodes.env_node"),
        spec("world_model", "lwm_nodes.world_model_node"),
        spec("planner", "lwm_nodes.planner_node"),
    ]
    if human == "scripted":
        nodes.append(spec("human", "lwm_nodes.human_node", final=True))
        nodes[-1].params["scripted"] = "true"
    elif human in ("page", "interactive"):
        nodes.append(
            spec("human", "lwm_nodes.human_node", interactive=human == "interactive", final=human == "interactive")
        )
    return nodes


def episode_file(run_dir: Path) -> Path:
    """Where a run's environment keeps the episode it plays (lwm_nodes/env_node.py): a restarted
    environment, or the run continued with --resume, returns to the episode under review."""
    return run_dir.resolve() / run_dirs.EPISODE_FILE


def fleet(nodes: list[NodeSpec], agents: int, seed: int, log_dir: Path) -> list[NodeSpec]:
    """The single agent's nodes made a fleet of `agents`: one world-model server serving them all
    (one model, its batches shared), and for each agent (agent1, agent2, ...) its environment,
    planner and reviewer in a namespace of its own. The agents play the same game from seeds SEED,
    SEED+1, ... (different boards, the same entities), each with its ledger and policies in
    LOG_DIR/<agent>/. The first agent's reviewer sends its language feedback to every agent
    (/feedback/manual): one manual re-plans the fleet."""
    names = [f"agent{i + 1}" for i in range(agents)]
    every = f"[{','.join(names)}]"  # the `agents` parameter of the nodes that serve them all
    out = []
    for spec in nodes:
        if spec.role in ("world_model", "live_view"):
            out.append(replace(spec, params={**spec.params, "agents": every}))
        elif spec.role == "recorder":
            out.append(spec)
        elif spec.role == "human" and "page_port" in spec.params:  # the person's fleet page, on PORT
            port = int(spec.params["page_port"])
            params = {"agents": every, "page_port": str(port), "first_agent_port": str(port + 1)}
            params.update({k: v for k, v in spec.params.items() if k in ("keys_file", "page_host")})
            config = spec.config.with_name(CONFIG_FILES["fleet_page"]) if spec.config else None
            out.append(NodeSpec("fleet_page", "lwm_nodes.fleet_page_node", params, config=config))
    for i, agent in enumerate(names):
        for spec in nodes:
            if spec.role in ("world_model", "live_view", "recorder"):
                continue
            params = dict(spec.params)
            if spec.role == "env":
                params["seed"] = str(seed + i)
                params["episode_file"] = str(episode_file(log_dir / agent))
            elif spec.role == "planner":
                params["ledger"] = str(log_dir / agent / run_dirs.LEDGER_FILE)
            elif spec.role == "human" and "page_port" in params:  # agent K's own review page, on PORT+K
                params["page_port"] = str(int(params["page_port"]) + i + 1)
            elif spec.role == "human":
                if i == 0:
                    params["manual_topic"] = "/feedback/manual"
                else:
                    params.pop("language", None)
                    params.pop("texts", None)
            out.append(replace(spec, name=f"{agent}/{spec.name}", namespace=agent, params=params))
    return out


def supervise(
    nodes: list[NodeSpec],
    log_dir: Path,
    ready_timeout: float,
    max_restarts: int,
    echo: bool,
    run_for: float | None = None,
) -> int:
    log_dir.mkdir(parents=True, exist_ok=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    procs = [Supervised(n, log_dir, echo) for n in nodes]
    for p in sorted(procs, key=lambda p: not p.spec.first):
        p.start()
        if p.spec.first:
            p.ready.wait(ready_timeout)
    for p in procs:
        if not p.ready.wait(ready_timeout):
            print(
                f"launcher: {p.spec.name} did not become ready in {ready_timeout:.0f} s; see {p.log_path}",
                file=sys.stderr,
            )
            stop.set()
            break
    else:
        print(f"launcher: all {len(procs)} nodes ready (logs in {log_dir})", flush=True)
    began = time.monotonic()
    finished: set[Supervised] = set()  # final nodes that have ended their work
    while not stop.is_set():
        if run_for is not None and time.monotonic() - began > run_for:
            break
        for p in procs:
            if p in finished:
                continue
            code = p.proc.poll()
            if code is not None and p.spec.final and code == 0:
                print(f"launcher: {p.spec.name} finished", flush=True)
                finished.add(p)
                if all(q in finished for q in procs if q.spec.final):  # a fleet's last reviewer
                    stop.set()
                    break
                continue
            if code is not None:
                p.exit_codes.append(code)
                if p.restarts >= max_restarts:
                    print(f"launcher: {p.spec.name} exited with {code}; no restarts left", file=sys.stderr)
                    stop.set()
                    break
                p.restarts += 1
                print(
                    f"launcher: {p.spec.name} exited with {code}; restart {p.restarts}/{max_restarts}",
                    file=sys.stderr,
                    flush=True,
                )
                p.start()
        time.sleep(0.2)
    stopping = time.monotonic()
    for p in procs:
        if not p.spec.first:
            p.signal(signal.SIGTERM)
    exits: dict[str, tuple[int, float]] = {}  # each node's exit code and seconds after SIGTERM
    last_signalled = False
    while len(exits) < len(procs) and time.monotonic() - stopping < 10:
        if not last_signalled and all(p.spec.name in exits for p in procs if not p.spec.first):
            last_signalled = True  # the others have exited: nothing more to record
            for p in procs:
                if p.spec.first:
                    p.signal(signal.SIGTERM)
        for p in procs:
            if p.spec.name not in exits and (code := p.proc.poll()) is not None:
                exits[p.spec.name] = (code, time.monotonic() - stopping)
        time.sleep(0.02)
    worst = 0
    for p in procs:
        if p.spec.name not in exits:
            p.proc.kill()
            exits[p.spec.name] = (p.proc.wait(), time.monotonic() - stopping)
        code, took = exits[p.spec.name]
        p.exit_codes.append(code)
        print(
            f"launcher: {p.spec.name} exit code {code} (restarts: {p.restarts}), {took:.2f} s after SIGTERM",
            flush=True,
        )
        worst = worst or (code if code not in (0, -signal.SIGTERM) else 0)
    return worst


def choose_run_dir(log_dir: Path | None, resume: Path | None) -> tuple[Path, Path]:
    """This run's directory and the default key file. A new run gets a new directory unless
    --log-dir names one; --resume continues the one it names (or logs/latest)."""
    if resume is not None:
        if log_dir is not None and resume != Path(run_dirs.LATEST) and resume.resolve() != log_dir.resolve():
            raise ValueError("--resume and --log-dir name different runs; give one of them")
        target = log_dir or (run_dirs.latest_run_dir() if resume == Path(run_dirs.LATEST) else resume)
        if target is None or not target.is_dir():
            raise ValueError(f"no earlier run to resume at {target or run_dirs.LOGS / run_dirs.LATEST}")
        if log_dir is None and target.resolve().parent == (run_dirs.LOGS / "runs").resolve():
            run_dirs.point_latest(target)
        keys = target / run_dirs.KEYS_FILE if log_dir is not None else run_dirs.LOGS / run_dirs.KEYS_FILE
        return target, keys
    if log_dir is not None:
        return log_dir, log_dir / run_dirs.KEYS_FILE
    return run_dirs.new_run_dir(), run_dirs.LOGS / run_dirs.KEYS_FILE


def describe_run(log_dir: Path, ledgers: list[Path], state: Path, resumed: bool) -> str:
    """What this run starts from, said before anything starts: a person must know whether the
    agent (or a fleet's agents, a ledger each) remembers an earlier review."""
    if not resumed:
        return (
            f"launcher: a new run in {log_dir}: no earlier reviews, the game's own manual, the shipped policy "
            f"(continue it later with --resume {log_dir})"
        )
    reviews, finished = 0, 0
    for ledger in ledgers:
        if not ledger.is_file():
            continue
        try:
            book = Ledger(ledger, read_only=True)
            summaries = book.summaries()
            book.close()
            reviews += len(summaries)
            finished += sum(s["report"] is not None for s in summaries)
        except (OSError, sqlite3.Error) as exc:
            return f"launcher: resuming {log_dir}; its ledger {ledger} cannot be read ({exc})"
    manual = ""
    if state.is_file():
        try:
            saved = json.loads(state.read_text())
            by_agent = saved["agents"] if "agents" in saved else {"": saved}
            versions = [f"{name + ' ' if name else ''}v{entry.get('version', '?')}" for name, entry in by_agent.items()]
            manual = f"; the world-model server's manual {', '.join(versions)}"
        except (OSError, ValueError, TypeError, AttributeError):
            manual = f"; the world-model server's state {state} cannot be read"
    return (
        f"launcher: resuming the run in {log_dir}: {reviews} review(s) in its ledger{'s' if len(ledgers) > 1 else ''}, "
        f"{finished} finished "
        f"(shown, not redone){manual}"
    )


def given_parameters(
    args: argparse.Namespace, human: str, ledger: Path, state: Path, keys_file: Path, person: str
) -> dict[str, dict[str, str]]:
    """Per node, the parameters this launch sets over the YAML files: the options the command line
    was given, and the run's own paths (ledger, manual state, key file)."""

    def chosen(**values) -> dict[str, str]:
        return {k: (str(v).lower() if isinstance(v, bool) else str(v)) for k, v in values.items() if v is not None}

    trust = chosen(keys_file=keys_file, trusted=args.trusted or None)
    texts = ",".join(args.texts) if args.texts else None
    given = {
        "env": chosen(
            split=args.split, index=args.index, seed=args.seed, texts=texts, episode_file=episode_file(args.log_dir)
        ),
        "world_model": chosen(checkpoint=args.checkpoint, state=state, **trust),
        "planner": chosen(
            ledger=ledger,
            policy=args.policy,
            iterations=args.iterations,
            futures=args.futures,
            constrained=args.constrained,
            constrained_learning=args.constrained_learning,
            **trust,
        ),
        "human": chosen(keys_file=keys_file),
    }
    if human == "scripted":
        # Nobody watches the scripted reviewer's screen: one line per plan unless --show-frames.
        given["human"].update(
            chosen(
                teach=args.teach, approve_return=args.approve_return, episodes=args.episodes, quiet=not args.show_frames
            )
        )
        if args.language:
            given["human"].update(chosen(language=True, texts=texts))
        if args.answer_questions:
            given["human"].update(chosen(questions=True))
    elif human == "page":
        given["human"].update(chosen(page_port=args.page, reviewer=person or None))
    elif human == "interactive":
        given["human"].update(chosen(reviewer=person))
    return given


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="run_nodes.sh", description="Start the LWM system's nodes.")
    parser.add_argument(
        "--checkpoint",
        default=None,
        help="the world model the world-model server serves (default: EMMA-LWM, reader tuned, hedged)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=CONFIG_DIR,
        help="directory of the nodes' parameter files (one YAML file per node, as in the lwm_nodes package's "
        "config/), each passed to its node with --params-file; the options below override single values "
        "(default: the package's config/)",
    )
    parser.add_argument("--split", default=None, help="split of the game the environment runs (default: newall-test)")
    parser.add_argument("--index", type=int, default=None, help="game index in the split (default 0)")
    parser.add_argument("--seed", type=int, default=None, help="episode seed (default 0)")
    parser.add_argument(
        "--log-dir",
        type=Path,
        default=None,
        help="this run's directory: each node's log, the review ledger, the world-model server's manual, the policy "
        "snapshots (default: a new logs/runs/<time>; logs/latest points at the newest)",
    )
    parser.add_argument(
        "--resume",
        nargs="?",
        type=Path,
        const=Path(run_dirs.LATEST),
        default=None,
        metavar="RUN_DIR",
        help="continue an earlier run: its reviews (a finished one is shown again, not redone), the manual the "
        "world-model server was given and the learnt policy (default RUN_DIR: the newest run, logs/latest)",
    )
    parser.add_argument(
        "--ready-timeout", type=float, default=120.0, help="seconds each node may take to say it is ready (default 120)"
    )
    parser.add_argument(
        "--max-restarts", type=int, default=3, help="times a node that dies is started again before the run ends"
    )
    parser.add_argument("--quiet", action="store_true", help="do not echo the nodes' output")
    parser.add_argument("--run-for", type=float, default=None, help="stop after this many seconds (demos, tests)")
    parser.add_argument("--policy", default=None, help="policy directory for the planner (default: shipped, if any)")
    parser.add_argument("--ledger", default=None, help="review ledger, SQLite (default: LOG_DIR/ledger.sqlite)")
    parser.add_argument(
        "--state",
        default=None,
        help="the world-model server's manual and version, kept across restarts "
        "(default: LOG_DIR/world_model_state.json)",
    )
    parser.add_argument(
        "--keys-file",
        type=Path,
        default=None,
        help="the reviewers' keys (JSON, mode 0600), created with random keys if missing; keep it out of git "
        "(default: logs/reviewer_keys.json, kept across runs; LOG_DIR/reviewer_keys.json when --log-dir is given)",
    )
    parser.add_argument(
        "--trusted",
        default="",
        help="comma-separated reviewer ids the planner and world-model server take feedback from "
        "(default: every reviewer in the key file)",
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="rounds of the agent's learning in imagination: on its own from each new manual, and when a reviewer "
        "teaches (default 10; 0: no learning from the manual alone)",
    )
    parser.add_argument("--futures", type=int, default=None, help="sampled futures shown with each plan (default 8)")
    parser.add_argument(
        "--constrained",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the plans and futures a person reviews are imagined under the game's rules (decoding constraints); "
        "--no-constrained shows the world model's raw samples",
    )
    parser.add_argument(
        "--constrained-learning",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="the planner's learning rounds (online imitation) are imagined under the game's rules too",
    )
    parser.add_argument(
        "--teach",
        choices=["online_il", "filtered_bc", "corrections", "none"],
        default=None,
        help="how the scripted reviewer teaches: label imagined states (online imitation), send its own plans "
        "(filtered BC), only correct, or none (with --language: the manual is all it gives)",
    )
    parser.add_argument(
        "--approve-return",
        type=float,
        default=None,
        help="the scripted reviewer approves at once a safe plan that imagines at least this return (a win with "
        "the message is +1.5; above it, the reviewer always teaches first)",
    )
    parser.add_argument(
        "--texts",
        nargs="+",
        default=None,
        help="human-written description files the game draws its manuals from, or stress:fresh (the project's "
        "fresh held-out descriptions, in people's own words; default: the project's generator)",
    )
    parser.add_argument(
        "--answer-questions",
        action="store_true",
        help="scripted: answer the question a plan asks about the manual's reading (the true fact) first",
    )
    parser.add_argument(
        "--episodes", type=int, default=None, help="scripted: episodes (seeds SEED, SEED+1, ...) to review (default 1)"
    )
    parser.add_argument(
        "--language",
        action="store_true",
        help="scripted: the reviewer's first answer is language feedback, the true manual in other words",
    )
    parser.add_argument("--show-frames", action="store_true", help="the scripted reviewer prints every plan's frames")
    parser.add_argument(
        "--only",
        default="",
        help="comma-separated nodes to start here (env, world_model, planner, human), the others running on "
        "another host of the same ROS domain (default: all)",
    )
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        help="record every topic to this MCAP file (Foxglove and rosbag2's MCAP storage open it; "
        "`lwm ros play` republishes it)",
    )
    parser.add_argument(
        "--reviewer",
        default=None,
        help="who reviews at the terminal or the page: their answers are signed with their own key (made in the "
        "key file if missing) and the ledger records them by this name (default: 'terminal' at the terminal; "
        "the page asks)",
    )
    parser.add_argument(
        "--agents",
        type=int,
        default=1,
        help="agents under review (2 or more: a fleet, agent1, agent2, ..., each with its environment, planner and "
        "reviewer in its own ROS namespace, all sharing one world-model server; they play the game from seeds SEED, "
        "SEED+1, ...; with --page PORT the fleet's queue is on PORT and agent K's review page on PORT+K; with "
        "--scripted the first reviewer's language feedback goes to every agent)",
    )
    parser.add_argument(
        "--foxglove",
        type=int,
        metavar="PORT",
        default=None,
        help="serve a live view on a Foxglove WebSocket at localhost:PORT (the real boards, the plans, their "
        "futures: open it in Foxglove); with --record, also written to FILE with .view.mcap in place of .mcap",
    )
    human = parser.add_mutually_exclusive_group()
    human.add_argument("--scripted", action="store_true", help="the simulated human reviews; exits with a summary")
    human.add_argument("--no-human", action="store_true", help="start no human-feedback node")
    human.add_argument(
        "--page",
        type=int,
        metavar="PORT",
        default=None,
        help="review in the browser: the human-feedback node serves the review page on localhost:PORT",
    )
    args = parser.parse_args(argv)
    if args.only and "simulator" in args.only.split(","):  # its name until 2026-11-26, kept as an alias
        args.only = ",".join("world_model" if n == "simulator" else n for n in args.only.split(","))
        print("launcher: --only simulator is now called world_model (the world-model server)", flush=True)
    ros_environment()
    try:
        args.log_dir, keys_default = choose_run_dir(args.log_dir, args.resume)
    except ValueError as exc:
        parser.error(str(exc))
    chosen = [f"--{name}" for name in ("split", "index", "seed") if getattr(args, name) is not None]
    saved = episode_file(args.log_dir)
    if args.resume is not None and chosen and saved.is_file():
        # The saved episode is the review the person left; a game chosen as well would silently lose.
        under_review = json.loads(saved.read_text()).get("episode_id", "?")
        parser.error(
            f"--resume returns to the episode under review ({under_review}); {' and '.join(chosen)} would start "
            "another: leave them out, and start another episode from the review once it runs (n SEED)"
        )
    ledger = Path(args.ledger) if args.ledger else args.log_dir / run_dirs.LEDGER_FILE
    state = Path(args.state) if args.state is not None else run_dirs.state_file(args.log_dir)
    missing = [name for name in CONFIG_FILES.values() if not (args.config / name).is_file()]
    if missing:
        parser.error(f"--config {args.config}: no {', '.join(missing)} there (copy the package's config/ and edit it)")
    if args.agents < 1:
        parser.error(f"--agents must be 1 or more, not {args.agents}")
    if args.agents > 1 and not (args.scripted or args.no_human or args.page is not None):
        parser.error(
            "a fleet (--agents 2 or more) is reviewed on the page (--page PORT: the fleet's queue on PORT, agent K's "
            "review page on PORT+K), by the scripted reviewer (--scripted) or from the command line (--no-human); "
            "the terminal reviews one agent"
        )
    ledgers = (
        [ledger]
        if args.agents == 1
        else [args.log_dir / f"agent{i + 1}" / run_dirs.LEDGER_FILE for i in range(args.agents)]
    )
    if args.resume is None and (args.only in ("", None) or "planner" in args.only or "world_model" in args.only):
        earlier = sorted({f for book in ledgers for f in run_dirs.earlier_run_files(book, state)})
        if earlier:
            parser.error(
                f"{', '.join(map(str, earlier))} hold(s) an earlier run's reviews or manual; pass --resume "
                f"{args.log_dir} to continue that run, or leave out --log-dir/--ledger/--state for a new one"
            )
    print(describe_run(args.log_dir, ledgers, state, args.resume is not None), flush=True)
    os.environ.setdefault("ROS_LOG_DIR", str(args.log_dir.resolve() / "ros"))
    if args.scripted:
        human = "scripted"
    elif args.page is not None:
        human = "page"
    elif args.no_human or not sys.stdin.isatty():
        human = "none"
    else:
        human = "interactive"
    keys_file = args.keys_file if args.keys_file is not None else keys_default
    # A new file gets both reviewers; an existing one (perhaps shared across hosts) only gains the
    # one this launch's human node signs as.
    person = args.reviewer or ("terminal" if human == "interactive" else "")
    try:
        if person:
            signing.check_reviewer_id(person)
    except signing.SigningError as exc:
        parser.error(f"--reviewer: {exc}")
    needed = {"scripted": ["scripted"], "interactive": [person], "page": [person] if person else []}.get(human, [])
    try:
        keys = signing.ensure_key_file(
            keys_file, needed if keys_file.exists() else sorted({*signing.DEFAULT_REVIEWERS, *needed})
        )
    except (OSError, signing.SigningError) as exc:
        parser.error(str(exc))
    print(f"launcher: reviewer keys for {', '.join(sorted(keys))} in {keys_file}", flush=True)
    nodes = default_nodes(human, given_parameters(args, human, ledger, state, keys_file, person), args.config)
    if args.foxglove is not None:
        view = {"port": str(args.foxglove)}
        if args.record is not None:
            view["mcap"] = str(args.record.resolve().with_suffix(".view.mcap"))
        nodes.append(
            NodeSpec("live_view", "lwm_nodes.live_view_node", view, config=args.config / CONFIG_FILES["live_view"])
        )
    if args.agents > 1:
        seed = args.seed if args.seed is not None else int(config_value(args.config, "env", "seed") or 0)
        nodes = fleet(nodes, args.agents, seed, args.log_dir)
    if args.only:
        wanted = {name.strip() for name in args.only.split(",") if name.strip()}
        unknown = wanted - {"env", "world_model", "planner", "human"}
        if unknown:
            parser.error(f"--only: unknown nodes {', '.join(sorted(unknown))} (env, world_model, planner, human)")
        # The live view, asked for by --foxglove, runs wherever it was asked; the fleet page goes with `human`.
        kept = {"live_view", *(["fleet_page"] if "human" in wanted else [])}
        nodes = [n for n in nodes if n.role in wanted or n.role in kept]
    if args.record is not None:
        for node in nodes:  # their services' requests and responses, as events the recorder takes
            if node.role in ("env", "world_model", "planner"):
                node.params["service_introspection"] = "contents"
        recorder = NodeSpec(
            "recorder",
            "lwm_nodes.recorder_node",
            {"path": str(args.record.resolve())},
            first=True,
            config=args.config / CONFIG_FILES["recorder"],
        )
        nodes.insert(0, recorder)
    echo = not args.quiet and human != "interactive"  # a person reads the human node's screen
    return supervise(nodes, args.log_dir, args.ready_timeout, args.max_restarts, echo, args.run_for)


if __name__ == "__main__":
    raise SystemExit(main())
