"""Training end to end on a tiny generated dataset: resumption, DDP with torchrun, evaluation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lwm_models.data.dataset import generate_dataset
from lwm_models.messenger.constants import DEFAULT_MAX_STEPS
from lwm_models.text import DescriptionPools
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.evaluate import ImaginationScore, imagination_metrics, loss_by_prefix
from lwm_models.world.imagine import Imagination
from lwm_models.world.tokens import DUMMY_ACTION, FIRST_REWARD_LABEL
from lwm_models.world.train import TrainArgs, evaluate_loss, train
from lwm_models.world.training_data import SplitTokens

VENV_BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    generate_dataset(out, DescriptionPools.generated(), max_games=12, train_episodes_per_game=6)
    return out


def args(data, out, **kw) -> TrainArgs:
    base = dict(
        data=str(data),
        out=str(out),
        kind="observational",
        preset="tiny",
        steps=8,
        batch=4,
        eval_every=4,
        eval_episodes=10,
        progress=False,
        lr=1e-3,
    )
    return TrainArgs(**{**base, **kw})


def test_training_lowers_the_loss_and_keeps_the_best(tiny_data, tmp_path):
    result = train(args(tiny_data, tmp_path / "run", steps=40, eval_every=20))
    lines = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    devs = [entry["dev_total"] for entry in lines if "dev_total" in entry]
    assert len(devs) == 2 and devs[-1] < devs[0]
    assert all("seed" in entry for entry in lines)
    model, config = load_checkpoint(tmp_path / "run" / "best")
    assert config["steps"] == 40 and config["dev"]["newall-dev"]["total"] == pytest.approx(result["best_dev"])


def test_resuming_continues_exactly(tiny_data, tmp_path):
    train(args(tiny_data, tmp_path / "straight", steps=8))
    train(args(tiny_data, tmp_path / "resumed", steps=4))
    train(args(tiny_data, tmp_path / "resumed", steps=8))
    a, _ = load_checkpoint(tmp_path / "straight" / "last")
    b, _ = load_checkpoint(tmp_path / "resumed" / "last")
    for (k, v), (_, w) in zip(a.state_dict().items(), b.state_dict().items()):
        torch.testing.assert_close(v, w, msg=k)


def test_a_killed_chunk_resumes_exactly(tiny_data, tmp_path):
    # A chunk killed after its last checkpoint leaves log lines past it, and possibly a half-done
    # swap of last/: the next chunk cuts the log, finishes the swap and trains on as if never stopped.
    train(args(tiny_data, tmp_path / "straight", steps=8))
    run = tmp_path / "resumed"
    first = train(args(tiny_data, run, steps=4))
    with open(run / "metrics.jsonl", "a") as f:
        f.write(json.dumps({"step": 6, "loss": 1.0}) + "\n" + '{"step": 7, "lo')
    (run / "last").rename(run / "last.old")
    (run / "last.new").mkdir()
    (run / "last.new" / "config.json").write_text("{")
    result = train(args(tiny_data, run, steps=8))
    a, _ = load_checkpoint(tmp_path / "straight" / "last")
    b, _ = load_checkpoint(run / "last")
    for (k, v), (_, w) in zip(a.state_dict().items(), b.state_dict().items()):
        torch.testing.assert_close(v, w, msg=k)
    assert not (run / "last.old").exists() and not (run / "last.new").exists()
    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [e["step"] for e in lines] == [4, 8]
    # The run's clock goes on from the first chunk's.
    clock = json.loads((run / "last" / "train_state.json").read_text())["clock"]
    assert first["cpu_s"] < clock["cpu_s"] <= result["cpu_s"]
    assert lines[0]["cpu_s"] <= round(first["cpu_s"], 1) <= lines[1]["cpu_s"]


def test_cpu_budget_counts_every_chunk(tiny_data, tmp_path):
    run = tmp_path / "run"
    first = train(args(tiny_data, run, steps=100, cpu_budget_minutes=1e-9))
    assert first["step"] == 1 and first["stopped"] == "CPU budget"
    again = train(args(tiny_data, run, steps=100, cpu_budget_minutes=1e-9))
    assert again["step"] == 1 and again["stopped"] == "CPU budget"
    more = train(args(tiny_data, run, steps=3, cpu_budget_minutes=None))
    assert more["step"] == 3 and more["stopped"] == "steps"


def test_decoder_overrides_reach_the_model(tiny_data, tmp_path):
    # --kv-heads and --attn-dropout replace the preset's values (recorded in the checkpoint config).
    train(args(tiny_data, tmp_path / "run", preset="small", steps=2, eval_every=2, kv_heads=4, attn_dropout=0.1))
    model, config = load_checkpoint(tmp_path / "run" / "last")
    assert config["config"]["decoder"]["kv_heads"] == 4 and config["config"]["decoder"]["attn_dropout"] == 0.1
    assert model.decoder_config.num_kv_heads == 4
    train(args(tiny_data, tmp_path / "default", preset="small", steps=2, eval_every=2))
    _, config = load_checkpoint(tmp_path / "default" / "last")
    assert config["config"]["decoder"]["kv_heads"] == 1 and config["config"]["decoder"]["attn_dropout"] == 0.0


def test_mixed_manuals_replace_descriptions_by_their_own_triple_s(tiny_data):
    data = SplitTokens(tiny_data, "train")
    own = list(data.texts)
    from lwm_models.messenger.constants import ALL_TRIPLES

    triples = [ALL_TRIPLES[i] for i in np.unique(np.asarray(data.ds.parses))]
    other = {t: [f"{t[0]} that {t[1]} is {t[2]} #{k}" for k in range(3)] for t in triples}
    data.mix_manuals(other, 0.5, encoder=None)
    rng = np.random.default_rng(0)
    swapped = kept = 0
    for _ in range(30):
        episodes, _starts = data._draw(rng, 8)
        ids = data._mixed_text_ids(rng, episodes)
        for e, row in zip(episodes, ids):
            for k, text_id in enumerate(row):
                if text_id == data.manuals[e, k]:
                    kept += 1
                else:
                    swapped += 1
                    assert data.texts[text_id] in other[ALL_TRIPLES[int(data.ds.parses[e][k])]]
    assert 0.35 < swapped / (swapped + kept) < 0.65
    assert data.texts[: len(own)] == own  # the dataset's texts keep their ids


def test_fine_tuning_starts_from_a_checkpoint_and_reads_longer_text(tiny_data, tmp_path):
    base = tmp_path / "base"
    train(args(tiny_data, base, kind="emma", steps=2, eval_every=2))
    start, _ = load_checkpoint(base / "last")
    tuned = tmp_path / "tuned"
    train(
        args(
            tiny_data,
            tuned,
            kind="emma",
            steps=1,
            eval_every=1,
            lr=1e-9,
            init=str(base / "last"),
            max_tokens=48,
            manual_mix=0.5,
            mix_per_style=2,
        )
    )
    model, config = load_checkpoint(tuned / "last")
    assert config["config"]["text"]["max_tokens"] == 48 and model.frozen_text_encoder().max_tokens == 48
    for (name, p), q in zip(model.named_parameters(), start.parameters()):
        assert torch.allclose(p, q, atol=1e-4), name  # one step at lr 1e-9 from the initial weights
    dev = [json.loads(line) for line in (tuned / "metrics.jsonl").read_text().splitlines() if "dev_total" in line]
    assert dev[-1]["dev_mixed_total"] > 0
    assert dev[-1]["dev_selection"] == pytest.approx((dev[-1]["dev_total"] + dev[-1]["dev_mixed_total"]) / 2)


def test_event_weighting_counts_the_steps_where_something_happens(tiny_data):
    """--event-weight: steps with a reward or the end are found from the tokens; weight 1 is the
    plain loss; a huge weight leaves only those steps' tokens in the loss."""
    import torch.nn.functional as F

    from lwm_models.world.base import event_steps, target_blocks
    from lwm_models.world.registry import PRESETS, build_model
    from lwm_models.world.train import batch_loss, weighted_objective

    torch.manual_seed(0)
    model = build_model("observational", PRESETS["tiny"]).eval()
    data = SplitTokens(tiny_data, "train")
    parts = data.sample_parts(np.random.default_rng(0), 16, 2)
    events = [event_steps(tokens) for tokens, _, _ in parts]
    for (tokens, lengths, _), ev in zip(parts, events):
        blocks = tokens.view(len(tokens), -1, 15)
        real = torch.arange(blocks.shape[1])[None, :] < lengths[:, None]
        # the dataset's rewards and dones, block by block, against what event_steps found
        rewarded = (blocks[:, :, 13] != FIRST_REWARD_LABEL) | (blocks[:, :, 14] == 1)
        assert torch.equal(ev & real, rewarded & real)
    assert sum(int(ev.sum()) for ev in events) > 0
    with torch.no_grad():
        plain, loss, kl = weighted_objective(model, None, parts, 1.0, 1.0)
        assert kl is None and float(loss) == pytest.approx(float(batch_loss([model(*p) for p in parts]).loss), rel=1e-5)
        _, heavy, _ = weighted_objective(model, None, parts, 1e9, 1.0)
        only_events = 0.0
        for name in ("obs", "reward", "done"):
            total = count = 0.0
            for (tokens, lengths, manual), ev in zip(parts, events):
                logits, target, mask = model.predictions(tokens, lengths, manual)[name]
                keep = mask & ev[:, target_blocks(tokens.shape[1])[name]]
                ce = F.cross_entropy(logits.transpose(1, 2), target, reduction="none")
                total, count = total + float((ce * keep).sum()), count + float(keep.sum())
            only_events += total / count
        assert float(heavy) == pytest.approx(only_events, rel=1e-4)
    assert float(plain.loss) == pytest.approx(float(loss), rel=1e-5)


def test_distillation_teaches_other_words_as_the_teacher_reads_the_dataset_s(tiny_data, tmp_path):
    """--distill: against itself, with the dataset's own descriptions, the KL term is 0; with other
    descriptions it is not, and training on it brings the model's reading of them towards the
    teacher's reading of the dataset's (the term falls). --select imagined-reward keeps the
    checkpoint with the best imagined reward precision on dev."""
    from lwm_models.world.shipped import shipped_checkpoint
    from lwm_models.world.train import weighted_objective

    base = shipped_checkpoint("emma")  # a model that reads its manual (a barely trained one does not)
    teacher, _ = load_checkpoint(base)
    student, _ = load_checkpoint(base)
    teacher.eval()
    student.eval()
    encoder = student.frozen_text_encoder()
    data = SplitTokens(tiny_data, "train", encoder)
    rng = np.random.default_rng(0)
    own = [(t, n, m, m) for t, n, m, _ in data.sample_parts(rng, 8, 2, own_manuals=True)]
    with torch.no_grad():
        _, _, kl = weighted_objective(student, teacher, own, 1.0, 1.0)
    assert float(kl) == pytest.approx(0.0, abs=1e-6)
    from lwm_models.messenger.constants import ALL_TRIPLES

    triples = [ALL_TRIPLES[i] for i in np.unique(np.asarray(data.ds.parses))]
    data.mix_manuals({t: [f"watch the {t[0]} #{k}" for k in range(2)] for t in triples}, 1.0, encoder)
    parts = data.sample_parts(rng, 8, 2, own_manuals=True)
    with torch.no_grad():
        _, _, before = weighted_objective(student, teacher, parts, 1.0, 1.0)
    assert float(before) > 1e-4

    run = tmp_path / "distilled"
    train(
        args(
            tiny_data,
            run,
            kind="emma",
            preset="small",
            steps=16,
            eval_every=8,
            lr=1e-3,
            init=str(base),
            distill=str(base),
            manual_mix=1.0,
            mix_per_style=2,
            select="imagined-reward",
            select_episodes=4,
        )
    )
    lines = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    dev = [entry for entry in lines if "dev_total" in entry]
    assert [d["step"] for d in dev] == [8, 16]
    for d in dev:
        assert 0 <= d["dev_reward_precision"] <= 1 and "dev_mixed_reward_precision" in d
        assert d["dev_selection"] == pytest.approx(-(d["dev_reward_precision"] + d["dev_mixed_reward_precision"]) / 2)
    best = min(dev, key=lambda d: d["dev_selection"])
    assert load_checkpoint(run / "best")[1]["steps"] == best["step"]
    tuned, _ = load_checkpoint(run / "last")
    tuned.eval()
    with torch.no_grad():
        _, _, after = weighted_objective(tuned, teacher, parts, 1.0, 1.0)
    assert float(after) < float(before)


def test_resume_refuses_another_model(tiny_data, tmp_path):
    train(args(tiny_data, tmp_path / "run", steps=2, eval_every=2))
    with pytest.raises(Exception, match="observational"):
        train(args(tiny_data, tmp_path / "run", steps=4, kind="oracle"))


def test_ddp_with_torchrun_on_two_cpu_processes(tiny_data, tmp_path):
    out = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [
        str(VENV_BIN / "torchrun"),
        "--standalone",
        "--nproc-per-node",
        "2",
        "-m",
        "lwm_models.cli.main",
        "train",
        "--data",
        str(tiny_data),
        "--out",
        str(out),
        "--kind",
        "oracle",
        "--preset",
        "tiny",
        "--steps",
        "4",
        "--batch",
        "4",
        "--eval-every",
        "4",
        "--eval-episodes",
        "5",
        "--no-progress",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    model, config = load_checkpoint(out / "last")
    assert config["steps"] == 4 and config["kind"] == "oracle"


def test_eval_metrics_and_prefix_curve(tiny_data):
    model, _ = load_checkpoint_or_new()
    data = SplitTokens(tiny_data, "newall-test")
    ce = evaluate_loss(model, data, limit=10)
    assert ce["total"] == pytest.approx(ce["obs"] + ce["reward"] + ce["done"])
    curve = loss_by_prefix(model, data, limit=10)
    assert curve["step"][0] == 1 and len(curve["total"]) == len(curve["step"])
    metrics = imagination_metrics(model, data, episodes=6)
    assert metrics.episodes == 6
    assert 0 <= metrics.reward_precision <= 1 and 0 <= metrics.termination_precision <= 1
    for rate in ("reward_recall", "termination_recall", "reward_without_reach", "avatar_jump_rate"):
        assert 0 <= getattr(metrics, rate) <= 1, rate
    # per transition, each of the 3 entity channels counted
    assert 0 <= metrics.identity_change_rate <= 3 and 0 <= metrics.vanish_rate <= 3
    assert metrics.real_reward_steps >= 0


def test_real_episodes_score_as_a_perfect_imagination(tiny_data):
    # Table 2's checks applied to the game itself: every real reward and end has its entity in
    # reach, every real reward and end is recalled, nothing changes identity, jumps or vanishes,
    # no rule is broken. A check that a real transition can fail would blame the model for it.
    data = SplitTokens(tiny_data, "newall-test")
    real = [data.ds[e] for e in range(len(data))]
    steps = DEFAULT_MAX_STEPS + 1
    n = len(real)
    im = Imagination(
        np.zeros((n, steps, 4, 3), np.uint8),
        np.zeros((n, steps), np.int64),
        np.zeros((n, steps), np.float32),
        np.zeros((n, steps), bool),
        np.array([len(ep.observations) for ep in real]),
        np.zeros((n, steps, 14), np.float32),
    )
    for i, ep in enumerate(real):
        k = len(ep.observations)
        im.observations[i, :k], im.actions[i, :k] = ep.observations, ep.actions
        im.rewards[i, :k], im.dones[i, :k] = ep.rewards, ep.dones
    im.actions[:, 0] = 0
    score = ImaginationScore()
    score.add(im, real)
    m = score.metrics()
    assert m.episodes == n and m.reward_steps == m.real_reward_steps > 0 and m.done_steps > 0
    assert m.reward_precision == m.termination_precision == m.reward_recall == m.termination_recall == 1.0
    assert m.delta_dist == 0 and m.reward_without_reach == 0
    assert m.identity_change_rate == m.avatar_jump_rate == m.vanish_rate == m.rule_breaks_per_step == 0
    assert m.identity_changes == m.avatar_jumps == 0
    assert m.transitions == sum(len(ep.observations) - 1 for ep in real) and m.avatar_moves > 0


def load_checkpoint_or_new():
    from lwm_models.world.registry import PRESETS, build_model

    torch.manual_seed(0)
    return build_model("observational", PRESETS["tiny"]).eval(), {}


def test_batches_follow_the_paper_recipe(tiny_data):
    data = SplitTokens(tiny_data, "train")
    # Every episode's blocks: the first is context (dummy action, reward label 2, not done), the
    # last is the only done one, and the actions are the episode's.
    for e in range(0, len(data), 5):
        lo, hi = data.offsets[e], data.offsets[e + 1]
        blocks = data.blocks[lo:hi]
        assert blocks[0, 0] == DUMMY_ACTION and blocks[0, -2] == FIRST_REWARD_LABEL and blocks[0, -1] == 0
        assert blocks[-1, -1] == 1 and not blocks[:-1, -1].any()
        assert (blocks[1:, 0] == np.asarray(data.ds.actions[lo + 1 : hi])).all()
    rng = np.random.default_rng(0)
    tokens, lengths, manual = data.sample(rng, 16)
    assert tokens.shape[0] == 16 and tokens.shape[1] == 15 * int(lengths.max())
    assert (lengths >= 2).all() and manual.parse.shape == (16, 3, 3)


def test_a_batch_in_parts_has_the_loss_and_gradient_of_one_batch(tiny_data):
    from lwm_models.world.registry import PRESETS, build_model
    from lwm_models.world.train import batch_loss

    torch.manual_seed(0)
    model = build_model("emma", PRESETS["tiny"]).eval()  # eval: no dropout, so the two are comparable
    data = SplitTokens(tiny_data, "train", model.frozen_text_encoder(), model.route)
    whole = data.sample(np.random.default_rng(3), 24)
    parts = data.sample_parts(np.random.default_rng(3), 24, 4)
    # The same segments, sorted by length and each part padded only to its own longest.
    assert len(parts) == 4 and sum(len(p[1]) for p in parts) == 24
    lengths = torch.cat([p[1] for p in parts])
    assert sorted(lengths.tolist()) == sorted(whole[1].tolist()) and lengths.tolist() == sorted(lengths.tolist())
    assert all(p[0].shape[1] == 15 * int(p[1].max()) for p in parts)
    assert sum(p[0].numel() for p in parts) < whole[0].numel()

    def loss_and_grads(outs):
        model.zero_grad()
        out = batch_loss(outs)
        out.loss.backward()
        return out, [p.grad.clone() for p in model.parameters() if p.grad is not None]

    one, one_grads = loss_and_grads([model(*whole)])
    split, split_grads = loss_and_grads([model(*p) for p in parts])
    for k in ("loss", "obs", "reward", "done"):
        assert getattr(split, k).item() == pytest.approx(getattr(one, k).item(), rel=1e-5)
    assert len(one_grads) == len(split_grads) > 10
    for a, b in zip(one_grads, split_grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
