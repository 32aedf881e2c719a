"""The figure `lwm train --select imagined-reward` chooses checkpoints by, for any checkpoint: imagined
reward and termination precision (Table 2, raw sampling) on the dev split, with the dataset's
descriptions and with the dev manuals re-drawn from the --manual-mix pool, and the dev
cross-entropy with each. Used to put a shipped model beside a fine-tune's evaluations in its
metrics.jsonl.

    .venv/bin/python benchmarks/imagined_rewards.py --data data/human --checkpoints DIR [DIR ...]
"""

from __future__ import annotations

import argparse
import json

import torch

from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.train import TrainArgs, evaluate_loss, imagined_precision, mix_pools
from lwm_models.world.training_data import SplitTokens, redraw_manuals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default="data/human", help="dataset directory (lwm data generate)")
    parser.add_argument("--checkpoints", nargs="+", required=True, help="checkpoint directories")
    parser.add_argument("--split", default="newall-dev")
    parser.add_argument("--episodes", type=int, default=300, help="dev episodes imagined (as --select-episodes)")
    parser.add_argument("--mix-per-style", type=int, default=12, help="as lwm train --mix-per-style")
    parser.add_argument("--mix-source", default="both", help="as lwm train --mix-source")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--loss-episodes", type=int, default=1000, help="dev episodes of the cross-entropy")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    for path in args.checkpoints:
        model, _ = load_checkpoint(path)
        train_args = TrainArgs(
            data=args.data,
            out="-",
            eval_split=args.split,
            manual_mix=1.0,  # only the pool's content matters here, not the rate
            mix_per_style=args.mix_per_style,
            mix_source=args.mix_source,
            seed=args.seed,
        )  # what mix_pools reads of a training run's arguments
        encoder = model.frozen_text_encoder()
        dev = SplitTokens(args.data, args.split, encoder, model.route)
        mixed = SplitTokens(args.data, args.split, encoder, model.route)
        redraw_manuals(mixed, mix_pools(mixed, train_args), encoder, seed=args.seed)
        figures = imagined_precision(model, dev, mixed, args.episodes, args.seed)
        # the cross-entropy lwm train's dev evaluation records beside them (its --eval-episodes 1000)
        figures["dev_total"] = evaluate_loss(model, dev, limit=args.loss_episodes)["total"]
        figures["dev_mixed_total"] = evaluate_loss(model, mixed, limit=args.loss_episodes)["total"]
        run = {"checkpoint": path, "split": args.split, "episodes": args.episodes, "seed": args.seed,
               "mix_source": args.mix_source}  # fmt: skip
        print(json.dumps({**run, **figures}))


if __name__ == "__main__":
    main()
