"""`lwm imagine`: imagine a game's trajectories with a world model and show them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import LwmError
from ..messenger.constants import ACTION_NAMES, DEFAULT_MAX_STEPS, NUM_ACTIONS, SPLITS
from ..messenger.policies import POLICIES
from .args import checkpoint_dir, nonnegative_int, positive_int

if TYPE_CHECKING:
    from ..world.imagine import Imagination


def action_list(text: str) -> list[int]:
    """--actions: comma-separated actions 0-4, e.g. 3,3,1."""
    try:
        actions = [int(a) for a in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers 0-4, got {text!r}") from None
    bad = [a for a in actions if not 0 <= a < NUM_ACTIONS]
    if bad:
        raise argparse.ArgumentTypeError(f"actions are 0-{NUM_ACTIONS - 1}, got {bad[0]}")
    return actions


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("imagine", help="imagine trajectories of a game with a world model")
    p.add_argument(
        "--checkpoint",
        type=checkpoint_dir,
        default=None,
        help="checkpoint directory (default: the shipped EMMA-LWM, reader tuned and hedged: emma-lwm-hedged)",
    )
    p.add_argument("--split", choices=SPLITS, default="newall-test", metavar="SPLIT", help="split of the game")
    p.add_argument("--index", type=nonnegative_int, default=0, help="game index in the split")
    p.add_argument(
        "--seed", type=nonnegative_int, default=0, help="seed of the real first observation and the sampling"
    )
    p.add_argument("--n", type=positive_int, default=1, help="number of trajectories")
    p.add_argument("--policy", choices=POLICIES, default="go_to_goal", help="behaviour policy that acts in imagination")
    p.add_argument(
        "--actions",
        type=action_list,
        default=None,
        metavar="A,A,...",
        help="comma-separated actions 0-4 instead of a policy (padded with 4, stay)",
    )
    p.add_argument("--max-steps", type=positive_int, default=DEFAULT_MAX_STEPS, help="time limit in actions")
    p.add_argument(
        "--texts", nargs="+", default=None, metavar="PATH", help="draw the manual from these description files"
    )
    p.add_argument(
        "--constrained", action="store_true", help="sample under the game's rules (decoding constraints), not raw"
    )
    p.add_argument("--png", type=Path, default=None, help="write the first trajectory as a PNG strip")
    p.add_argument("--json", action="store_true", help="print the trajectories as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..data.splits import load_split
    from ..text import DescriptionPools

    # The game and the manual's files are checked before torch and the model load, which take seconds.
    games = load_split(args.split)
    if not 0 <= args.index < len(games):
        raise LwmError(f"--index must be in 0..{len(games) - 1} for {args.split}")
    game = games[args.index]
    pools = DescriptionPools.from_files(args.texts) if args.texts else DescriptionPools.generated()

    from ..agent.expert import expert_policy
    from ..messenger.engine import BatchedMessenger
    from ..messenger.render import render_ascii, render_trajectory_png
    from ..world.checkpoint import load_checkpoint
    from ..world.imagine import imagine
    from ..world.shipped import SYSTEM_WORLD_MODEL, shipped_checkpoint

    path = args.checkpoint or shipped_checkpoint(SYSTEM_WORLD_MODEL)
    model, config = load_checkpoint(path)
    engine = BatchedMessenger(max_steps=args.max_steps)
    engine.reset([game], [args.seed])
    first = engine.compact_observation()[0]
    rng = np.random.default_rng(args.seed)
    manual = pools.draw(args.split, list(game.triples), rng)
    batch = model.read_manual(manual, model.frozen_text_encoder(), list(game.triples))
    if args.actions:
        acts = (args.actions + [4] * args.max_steps)[: args.max_steps]
        im = imagine(
            model,
            batch,
            first,
            n=args.n,
            actions=np.array(acts),
            max_steps=args.max_steps,
            seed=args.seed,
            constrained=args.constrained,
        )
    else:
        im = imagine(
            model,
            batch,
            first,
            n=args.n,
            policy=expert_policy(game, args.seed, args.policy),
            max_steps=args.max_steps,
            seed=args.seed,
            constrained=args.constrained,
        )
    if args.json:
        print(json.dumps(im.to_json()))
        return 0
    print(f"game {args.split}[{args.index}]: {game}")
    print("manual:")
    for d in manual:
        print(f"  - {d}")
    show(im, 0, render_ascii)
    print(f"imagined returns of {args.n} trajectories: {np.round(im.returns, 2).tolist()}")
    if args.png:
        n = int(im.lengths[0])
        render_trajectory_png(im.observations[0, :n], args.png, rewards=im.rewards[0, :n], actions=im.actions[0, :n])
        print(f"trajectory written to {args.png}")
    return 0


def show(im: Imagination, i: int, render) -> None:
    conf = im.confidence()
    for t in range(int(im.lengths[i])):
        if t == 0:
            head = "start"
        else:
            action = ACTION_NAMES[im.actions[i, t]]
            head = f"step {t}: {action}, reward {im.rewards[i, t]:+.1f}, confidence {conf[i, t]:.2f}"
        print(head + (" (done)" if im.dones[i, t] else ""))
        print(render(im.observations[i, t]))
