"""World models: tokenizer, decoder with KV cache, families, checkpoints."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lwm_models.data.splits import load_split
from lwm_models.errors import ShapeError
from lwm_models.messenger import rollout
from lwm_models.world.base import ManualBatch
from lwm_models.world.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from lwm_models.world.imagine import imagine
from lwm_models.world.registry import KINDS, PRESETS, build_model
from lwm_models.world.tokens import (
    BLOCK,
    obs_to_tokens,
    reward_label,
    tokens_to_obs,
)


@pytest.fixture(scope="module")
def episodes():
    games = load_split("train")[:40]
    return rollout(games, np.arange(40), np.arange(40) % 5)


def fake_manual(b: int, seed: int = 0) -> ManualBatch:
    g = torch.Generator().manual_seed(seed)
    lengths = torch.randint(5, 20, (b, 3), generator=g)
    mask = torch.arange(36)[None, None] < lengths[..., None]
    parse = torch.stack(
        [torch.tensor([[4, 12, 10]] * b), torch.randint(0, 3, (b, 3), generator=g), torch.tensor([[0, 1, 2]] * b)], -1
    )
    return ManualBatch(torch.randn(b, 3, 36, 384, generator=g), mask, parse, torch.tensor([[4, 12, 10]] * b))


def test_tokens_round_trip_exactly(episodes):
    obs = episodes.observations
    tokens = obs_to_tokens(obs)
    assert tokens.shape == obs.shape[:-2] + (12,)
    np.testing.assert_array_equal(tokens_to_obs(tokens), obs)
    empty = np.zeros((4, 3), dtype=np.uint8)
    assert obs_to_tokens(empty).tolist() == [0, 17, 27] * 4


def test_tokens_out_of_their_slot_range_are_clipped_and_id_0_empties_a_channel():
    # A model may sample any observation token at any slot: an id slot holding a row token, a row
    # slot holding an id, and (from a caller) values below or above every vocabulary.
    tokens = np.array([[20, 3, 40, 5, 30, 20, -3, 18, 28, 16, 26, 99]])
    # channel 0: id 20 is no id -> empty; 1: id 5, row 30-17 clipped to 9, column 20-27 clipped to 0;
    # 2: id -3 -> empty; 3: id 16, row 26-17 = 9, column 99 -> 9
    assert tokens_to_obs(tokens).tolist() == [[[0, 0, 0], [5, 9, 0], [0, 0, 0], [16, 9, 9]]]
    assert tokens_to_obs(tokens).dtype == np.uint8


def test_reward_labels():
    assert reward_label(np.array([-1.0, 0.0, 0.5, 1.0])).tolist() == [0, 2, 3, 4]
    with pytest.raises(ValueError):
        reward_label(2.0)


def test_shape_errors():
    with pytest.raises(ShapeError):
        obs_to_tokens(np.zeros((3, 3)))
    with pytest.raises(ShapeError):
        tokens_to_obs(np.zeros(11))


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_family_trains_and_masks_padding(kind):
    torch.manual_seed(0)
    model = build_model(kind, PRESETS["tiny"])
    tokens = torch.randint(0, 2, (3, 4 * BLOCK))
    lengths = torch.tensor([4, 2, 3])
    manual = fake_manual(3)
    out = model(tokens, lengths, manual)
    # Obs targets: blocks 1..len-1, 12 tokens each; padding beyond a sequence's length is masked.
    assert int(out.counts["obs"]) == 12 * (3 + 1 + 2)
    assert int(out.counts["reward"]) == 6 and int(out.counts["done"]) == 6
    out.loss.backward()
    changed = tokens.clone()
    changed[1, 2 * BLOCK :] = 1  # padding of sequence 1
    model.eval()
    a, b = model(tokens, lengths, manual), model(changed, lengths, manual)
    assert torch.allclose(a.loss, b.loss)


def test_emma_reads_the_manual_and_observational_does_not():
    torch.manual_seed(0)
    tokens = torch.randint(0, 2, (2, 3 * BLOCK))
    tokens[:, 1] = 4  # an entity id token
    lengths = torch.tensor([3, 3])
    emma = build_model("emma", PRESETS["tiny"]).eval()
    obs = build_model("observational", PRESETS["tiny"]).eval()
    m1, m2 = fake_manual(2, seed=1), fake_manual(2, seed=2)
    # The value projection starts at zero: an untrained EMMA-LWM ignores its manual...
    assert torch.allclose(emma(tokens, lengths, m1).loss, emma(tokens, lengths, m2).loss)
    with torch.no_grad():  # ...and reads it once that projection has learned anything.
        torch.nn.init.normal_(emma.reader.v.weight, std=0.5)
    assert not torch.allclose(emma(tokens, lengths, m1).loss, emma(tokens, lengths, m2).loss)
    assert torch.allclose(obs(tokens, lengths, m1).loss, obs(tokens, lengths, m2).loss)


@pytest.mark.parametrize("kind", ["emma", "standard"])
def test_kv_cache_matches_full_recompute(kind):
    torch.manual_seed(0)
    model = build_model(kind, PRESETS["tiny"]).eval()
    manual = fake_manual(2)
    tokens = torch.randint(0, 2, (2, 3 * BLOCK))
    cond = model.condition(manual)
    full = model.hidden_states(tokens, cond)
    cache = model.new_cache(2)
    parts = [model.hidden_states(tokens[:, :BLOCK], cond, cache)]
    for i in range(BLOCK, 3 * BLOCK, 2):
        parts.append(model.hidden_states(tokens[:, i : i + 2], cond, cache))
    torch.testing.assert_close(torch.cat(parts, 1), full, rtol=1e-4, atol=1e-5)


def test_kv_cache_rows_join_and_leave_at_their_own_lengths():
    # Sequences that started at different times share one cache (extend), one leaves (select),
    # and each goes on as it would in a cache of its own. The columns past the end hold nothing
    # yet: poisoned with NaN here, they must never be read.
    torch.manual_seed(0)
    model = build_model("emma", PRESETS["tiny"]).eval()
    cond = model.condition(fake_manual(3))
    rows = [cond.index(torch.tensor([i])) for i in range(3)]
    tokens = torch.randint(0, 2, (3, 4 * BLOCK))
    starts = [2 * BLOCK, BLOCK, 3 * BLOCK]  # tokens each row has fed before they share a cache

    def alone(i: int, upto: int) -> torch.Tensor:
        return model.hidden_states(tokens[i : i + 1, :upto], rows[i])[:, -1]

    caches = []
    for i, n in enumerate(starts):
        caches.append(model.new_cache(1))
        model.hidden_states(tokens[i : i + 1, :n], rows[i], caches[-1])
    shared = caches[0]
    shared.extend(caches[1])
    shared.extend(caches[2])
    shared.k[:, :, :, shared.end :] = float("nan")
    shared.v[:, :, :, shared.end :] = float("nan")
    both = type(cond).cat(rows)
    new = torch.stack([tokens[i, n] for i, n in enumerate(starts)])[:, None]
    h = model.hidden_states(new, both, shared)[:, -1]
    for i, n in enumerate(starts):
        torch.testing.assert_close(h[i : i + 1], alone(i, n + 1), rtol=1e-4, atol=1e-5)
    shared.select(torch.tensor([0, 1]))  # the longest leaves: the others move left
    assert shared.end == starts[0] + 1
    shared.k[:, :, :, shared.end :] = float("nan")
    shared.v[:, :, :, shared.end :] = float("nan")
    new = torch.stack([tokens[i, n + 1] for i, n in enumerate(starts[:2])])[:, None]
    h = model.hidden_states(new, type(cond).cat(rows[:2]), shared)[:, -1]
    for i, n in enumerate(starts[:2]):
        torch.testing.assert_close(h[i : i + 1], alone(i, n + 2), rtol=1e-4, atol=1e-5)


def test_imagination_with_and_without_cache_agree(episodes):
    torch.manual_seed(0)
    model = build_model("emma", PRESETS["tiny"]).eval()
    manual = fake_manual(1)
    first = episodes.observations[0, 0]
    actions = np.full((4, 32), 4)
    a = imagine(model, manual, first, n=4, actions=actions, seed=3, max_steps=6)
    b = imagine(model, manual, first, n=4, actions=actions, seed=3, max_steps=6, use_cache=False)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.lengths, b.lengths)
    assert (a.observations[:, 0] == first).all()
    assert a.token_probs[:, 1].min() > 0


def test_imagination_with_a_policy_and_bad_inputs(episodes):
    model = build_model("observational", PRESETS["tiny"]).eval()
    calls = []

    def policy(obs, idx, t):
        calls.append((obs.shape, t))
        return np.full(len(idx), 1)

    im = imagine(model, ManualBatch(), episodes.observations[0, 0], n=3, policy=policy, seed=0, max_steps=4)
    assert calls[0] == ((3, 1, 4, 3), 1)
    assert (im.actions[:, 1] == 1).all()
    with pytest.raises(ValueError):
        imagine(model, ManualBatch(), episodes.observations[0, 0], n=1, seed=0)
    with pytest.raises(ShapeError):
        imagine(model, ManualBatch(), np.zeros((3, 3)), n=1, actions=np.zeros(32, dtype=int))
    with pytest.raises(ValueError):
        imagine(model, ManualBatch(), episodes.observations[0, 0], n=1, actions=np.full(32, 7))


def test_checkpoint_round_trip_and_corruption(tmp_path):
    model = build_model("emma", PRESETS["tiny"])
    path = save_checkpoint(model, tmp_path / "ckpt", {"steps": 3}, dtype=torch.float16)
    loaded, config = load_checkpoint(path)
    assert config["kind"] == "emma" and config["steps"] == 3
    for (k, v), (k2, v2) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert k == k2
        torch.testing.assert_close(v.half().float(), v2)
    with pytest.raises(CheckpointError, match="holds a 'emma'"):
        load_checkpoint(path, kind="observational")
    weights = path / "model.safetensors"
    data = weights.read_bytes()
    weights.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_checkpoint(path)
    weights.write_bytes(data)
    cfg = json.loads((path / "config.json").read_text())
    cfg["config"]["decoder"]["hidden"] = 64
    (path / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(CheckpointError, match="does not fit"):
        load_checkpoint(path)
    cfg["kind"] = "transformer-xl"
    (path / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(CheckpointError, match="unknown model kind"):
        load_checkpoint(path)
    with pytest.raises(CheckpointError, match="no config.json"):
        load_checkpoint(tmp_path / "nowhere")


def test_export_to_fp16_for_shipping(tmp_path):
    import subprocess
    import sys

    model = build_model("emma", PRESETS["tiny"])
    save_checkpoint(model, tmp_path / "run", {"steps": 7, "preset": "tiny"})
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "lwm_models.cli.main",
            "export",
            "--checkpoint",
            str(tmp_path / "run"),
            "--out",
            str(tmp_path / "ship"),
            "--fp16",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    shipped, config = load_checkpoint(tmp_path / "ship")
    assert config["dtype"] == "float16" and config["steps"] == 7 and config["exported_from"].endswith("run")
    assert (tmp_path / "ship" / "model.safetensors").stat().st_size < (
        tmp_path / "run" / "model.safetensors"
    ).stat().st_size


def test_consistency_counts_are_zero_on_the_real_game_and_see_each_fault():
    from lwm_models.world.evaluate import consistency_counts

    games = load_split("newall-test")[:200]
    ro = rollout(games, np.arange(200) * 13 + 5, np.arange(200) % 5)
    real = consistency_counts(ro.observations, ro.rewards, ro.lengths)
    assert real["transitions"] == int((ro.lengths - 1).sum()) and real["avatar_moves"] > 0
    assert real["identity_changes"] == real["vanished_without_reward"] == real["avatar_jumps"] == 0
    # One trajectory with each fault once: a channel's id changes at step 1, the avatar jumps two
    # cells at step 2, and an entity disappears at step 3 with reward 0.
    obs = np.zeros((1, 4, 4, 3), dtype=np.uint8)
    obs[0, :, 0] = [2, 1, 1]
    obs[0, :, 1] = [4, 8, 8]
    obs[0, :, 2] = [9, 3, 3]
    obs[0, :, 3] = [15, 5, 5]
    obs[0, 1:, 0, 0] = 3
    obs[0, 2:, 3, 1] = 7
    obs[0, 3:, 1] = 0
    fake = consistency_counts(obs, np.zeros((1, 4)), np.array([4]))
    assert fake == {
        "transitions": 3,
        "identity_changes": 1,
        "vanished_without_reward": 1,
        "avatar_moves": 3,
        "avatar_jumps": 1,
    }
