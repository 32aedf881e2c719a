"""`lwm imagine`: imagine a game's trajectories with a world model and show them."""

from __future__ import annotations

import argparse
import json

import numpy as np

from ..agent.expert import expert_policy
from ..data.splits import load_split
from ..errors import LwmError
from ..messenger.constants import ACTION_NAMES
from ..messenger.engine import BatchedMessenger
from ..messenger.policies import POLICIES
from .checkpoint import load_checkpoint
from .frozen_text import FrozenTextEncoder
from .imagine import Imagination, imagine
from .manual import manual_batch
from .registry import NEEDS_TEXT
from .shipped import shipped_checkpoint


def run_imagine(args: argparse.Namespace) -> int:
    from ..messenger.render import render_ascii, render_trajectory_png
    from ..text import DescriptionPools

    path = args.checkpoint or shipped_checkpoint("emma")
    model, config = load_checkpoint(path)
    games = load_split(args.split)
    if not 0 <= args.index < len(games):
        raise LwmError(f"--index must be in 0..{len(games) - 1} for {args.split}")
    game = games[args.index]
    pools = DescriptionPools.from_files(args.texts) if args.texts else DescriptionPools.generated()
    engine = BatchedMessenger(max_steps=args.max_steps)
    engine.reset([game], [args.seed])
    first = engine.compact_observation()[0]
    rng = np.random.default_rng(args.seed)
    manual = pools.draw(args.split, list(game.triples), rng)
    encoder = FrozenTextEncoder() if NEEDS_TEXT[config["kind"]] else None
    batch = manual_batch(config["kind"], manual, encoder, list(game.triples))
    if args.actions:
        try:
            acts = [int(a) for a in args.actions.split(",")]
        except ValueError:
            raise LwmError("--actions is a comma-separated list of integers 0-4") from None
        acts = (acts + [4] * args.max_steps)[: args.max_steps]
        im = imagine(model, batch, first, n=args.n, actions=np.array(acts), max_steps=args.max_steps, seed=args.seed)
    else:
        if args.policy not in POLICIES:
            raise LwmError(f"--policy must be one of {list(POLICIES)}")
        im = imagine(
            model,
            batch,
            first,
            n=args.n,
            policy=expert_policy(game, args.seed, args.policy),
            max_steps=args.max_steps,
            seed=args.seed,
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
