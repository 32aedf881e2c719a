"""The fast decoding paths of imagination (world/decoding.py) against the reference path: same seed,
same starts, same tokens, with the shipped EMMA-LWM and Observational checkpoints.

The flat decoder runs the reference's ops in the same order and must give its hidden states bit for
bit. The fast paths sample with the three output heads stacked per slot (batched matmuls) and the
speculative path computes a token's distribution in calls over several tokens, so their
probabilities may differ by rounding; the bound documented in world/speculative.py and
docs/speed.md is checked here (PROB_BOUND), and the sampled tokens must be identical.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from game_fixtures import MANUAL, OBS

from lwm_models.data.splits import load_split
from lwm_models.messenger.engine import BatchedMessenger
from lwm_models.world import speculative
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.continuous import ContinuousBatch, OneShot
from lwm_models.world.decoding import default_decoding, make_decoder_batch
from lwm_models.world.flat_decoder import FlatDecoder, _chunks, _Step, scripted
from lwm_models.world.imagine import DecoderBatch, StepwiseImagination, board_of, condition_rows, imagine
from lwm_models.world.registry import PRESETS, build_model
from lwm_models.world.shipped import shipped_checkpoint
from lwm_models.world.speculative import FlatDecoderBatch
from lwm_models.world.tokens import first_block_tokens, obs_to_tokens

PROB_BOUND = 1e-5  # the largest difference of a token's probability, a fast path vs reference
STEPS = 12


@pytest.fixture(scope="module", params=["emma", "observational"])
def shipped(request):
    """(model, manual batch) of a shipped checkpoint, on MANUAL."""
    model, _ = load_checkpoint(shipped_checkpoint(request.param))
    return model, model.read_manual(MANUAL, model.frozen_text_encoder())


@pytest.fixture(scope="module")
def starts() -> np.ndarray:
    """Six fixed start observations: the fixtures' one and the first of five newall-test games."""
    games = load_split("newall-test")[:5]
    engine = BatchedMessenger()
    engine.reset(games, list(range(len(games))))
    return np.concatenate([np.array(OBS, dtype=np.uint8)[None], engine.compact_observation()])


def run(model, manual, first, decoding: str, constrained: bool = False, seed: int = 0, stop_on_done: bool = True):
    n = len(first)
    actions = np.random.default_rng(seed).integers(5, size=(n, STEPS))
    return imagine(
        model,
        manual,
        first,
        n=n,
        actions=actions,
        max_steps=STEPS,
        seed=seed,
        stop_on_done=stop_on_done,
        constrained=constrained,
        decoding=decoding,
    )


def assert_same_tokens(a, b) -> None:
    np.testing.assert_array_equal(a.lengths, b.lengths)
    np.testing.assert_array_equal(a.observations, b.observations)
    np.testing.assert_array_equal(a.actions, b.actions)
    np.testing.assert_array_equal(a.rewards, b.rewards)
    np.testing.assert_array_equal(a.dones, b.dones)


@pytest.mark.parametrize("constrained", [False, True], ids=["raw", "constrained"])
@pytest.mark.parametrize("size", [1, 6])
def test_fast_paths_sample_the_reference_tokens(shipped, starts, size, constrained):
    model, manual = shipped
    first = starts[:size]
    reference = run(model, manual, first, "reference", constrained)
    flat = run(model, manual, first, "flat", constrained)
    fast = run(model, manual, first, "speculative", constrained)
    assert_same_tokens(flat, reference)
    np.testing.assert_allclose(flat.token_probs, reference.token_probs, rtol=0, atol=PROB_BOUND)
    assert_same_tokens(fast, reference)
    np.testing.assert_allclose(fast.token_probs, reference.token_probs, rtol=0, atol=PROB_BOUND)


def test_speculation_past_a_done_and_over_many_rows(shipped, starts):
    # Trajectories imagined past their done (as the benchmarks run them), 24 rows of mixed starts.
    model, manual = shipped
    first = np.concatenate([starts] * 4)
    reference = run(model, manual, first, "reference", seed=5, stop_on_done=False)
    fast = run(model, manual, first, "speculative", seed=5, stop_on_done=False)
    assert_same_tokens(fast, reference)
    np.testing.assert_allclose(fast.token_probs, reference.token_probs, rtol=0, atol=PROB_BOUND)


def test_rows_cut_into_groups_on_lanes_sample_what_one_group_samples(shipped, starts, monkeypatch):
    # 24 rows are stepped as groups on the lanes (lanes.py) on a machine with 2 cores or more; the
    # rows are independent, so the tokens are those of one group over all rows.
    model, manual = shipped
    first = np.concatenate([starts] * 4)
    ran = []
    lanes = speculative.lanes()
    if lanes is None:
        pytest.skip("one core: a step is never cut into groups")
    original = lanes.run
    monkeypatch.setattr(lanes, "run", lambda work: ran.append(len(work)) or original(work))
    cut = run(model, manual, first, "speculative", seed=3, stop_on_done=False)
    assert ran and set(ran) == {min(lanes.count, len(first) // speculative.MIN_GROUP)}
    monkeypatch.setattr(speculative, "MIN_GROUP", len(first) + 1)
    cut_runs = len(ran)
    whole = run(model, manual, first, "speculative", seed=3, stop_on_done=False)
    assert len(ran) == cut_runs  # the whole group ran on the caller's thread
    assert_same_tokens(cut, whole)
    np.testing.assert_allclose(cut.token_probs, whole.token_probs, rtol=0, atol=PROB_BOUND)


def test_the_comparison_can_fail(shipped, starts):
    # Another seed samples other tokens: the equality above is not vacuous.
    model, manual = shipped
    a = run(model, manual, starts, "speculative", seed=0)
    b = run(model, manual, starts, "speculative", seed=1)
    assert not np.array_equal(a.observations, b.observations)


def test_the_draft_decides_speed_not_tokens(shipped, starts, monkeypatch):
    # A draft that is always wrong (every token 0) samples the same tokens. It costs more calls, but
    # not a call per token: after the first call a row's draft is what that call sampled.
    model, manual = shipped
    reference = run(model, manual, starts, "reference", seed=2)

    class WrongDrafts(speculative._Speculator):
        def _draft(self, last: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
            return torch.zeros(last.shape[0], 14, dtype=torch.long)

    def calls_per_step() -> float:
        # One row alone feeds its whole draft per call (no lookahead limit): calls count re-drafts.
        rollout = StepwiseImagination(model, manual, starts[:1], 1, STEPS, seed=2, stop_on_done=False)
        for action in np.random.default_rng(2).integers(5, size=(STEPS, 1)):
            rollout.step(action)
        return rollout._rows.calls / STEPS

    right = calls_per_step()
    # The scripted graph drafts every step: the model's kept one is swapped for one of wrong drafts
    # (and put back after the test).
    kept = model.__dict__["_per_weights"]
    monkeypatch.setitem(kept, "speculator", (kept["speculator"][0], scripted(WrongDrafts(model).eval())))
    rollout = StepwiseImagination(model, manual, starts, len(starts), STEPS, seed=2, decoding="speculative")
    actions = np.random.default_rng(2).integers(5, size=(len(starts), STEPS))
    while not rollout.finished:
        rollout.step(actions[rollout.active, rollout.t])
    assert_same_tokens(rollout.result(), reference)
    assert right < calls_per_step() < speculative.STEP_TOKENS / 2


@pytest.mark.parametrize("drift", [0, 1])
@pytest.mark.parametrize("stop_on_done", [True, False], ids=["to-done", "past-done"])
def test_a_whole_run_samples_what_steps_sample(shipped, starts, stop_on_done, drift, monkeypatch):
    # A whole run of known actions (`StepwiseImagination.run`) takes every step in the scripted
    # graph, a row starting its next step once no row of its group is more than `drift` steps
    # behind: the tokens of stepping all rows together; with a drift, in fewer calls.
    model, manual = shipped
    first = np.concatenate([starts] * 2)
    actions = np.random.default_rng(7).integers(5, size=(len(first), STEPS))
    monkeypatch.setattr(speculative, "DRIFT", drift)

    def imagined(whole: bool):
        rollout = StepwiseImagination(model, manual, first, len(first), STEPS, seed=7, stop_on_done=stop_on_done)
        if whole:
            rollout.run(actions)
        while not rollout.finished:
            rollout.step(actions[rollout.active, rollout.t])
        assert rollout.finished and not (stop_on_done and rollout.dones[rollout.active].any())
        return rollout.result(), rollout._rows.calls

    (ahead, ahead_calls), (stepped, stepped_calls) = imagined(True), imagined(False)
    assert_same_tokens(ahead, stepped)
    np.testing.assert_allclose(ahead.token_probs, stepped.token_probs, rtol=0, atol=PROB_BOUND)
    assert (ahead.lengths < STEPS + 1).any() == stop_on_done  # some trajectory ended early
    assert ahead_calls <= stepped_calls and (drift == 0 or ahead_calls < stepped_calls)


def test_a_whole_run_checks_its_actions(shipped, starts):
    model, manual = shipped
    rollout = StepwiseImagination(model, manual, starts, len(starts), STEPS, seed=0)
    with pytest.raises(ValueError, match="actions"):
        rollout.run(np.zeros((len(starts), STEPS - 1), dtype=np.int64))
    with pytest.raises(ValueError, match="actions"):
        rollout.run(np.full((len(starts), STEPS), 5))
    rollout.run(np.zeros((len(starts), STEPS), dtype=np.int64))
    assert rollout.finished and (rollout.lengths > 1).all()
    rollout.run(np.zeros((len(rollout.active), 0), dtype=np.int64))  # nothing left to take


def test_continuous_batching_on_the_fast_path(shipped, starts):
    # Tracks join a running batch at different steps and leave at their own end: each row gets
    # the tokens the reference path gives it, whatever shares its calls.
    model, manual = shipped
    cond = model.condition_on(manual)

    def shots() -> list[OneShot]:
        out = []
        for i in range(3):
            n = 2 + i
            first = starts[i : i + n]
            actions = np.random.default_rng(i).integers(5, size=(n, STEPS))
            out.append(OneShot(condition_rows(cond, n), first, actions, STEPS - 3 * i, seed=i, constrained=i == 1))
        return out

    def served(decoding: str) -> list:
        batch, pending, done = ContinuousBatch(model, decoding=decoding), shots(), []
        while pending or len(batch):
            if pending and (batch.steps % 2 == 0 or not len(batch)):
                batch.admit(pending.pop(0))
            done += batch.step() if len(batch) else []
        return [t.result() for t in sorted(done, key=lambda t: t.seed)]

    for fast, reference in zip(served("speculative"), served("reference"), strict=True):
        assert_same_tokens(fast, reference)


def test_the_default_is_speculative_and_the_reference_stays_selectable(shipped, monkeypatch):
    model, _ = shipped
    monkeypatch.delenv("LWM_DECODING", raising=False)
    assert default_decoding() == "speculative"
    assert isinstance(make_decoder_batch(model), FlatDecoderBatch)
    assert type(make_decoder_batch(model, "reference")) is DecoderBatch
    assert type(make_decoder_batch(model, use_cache=False)) is DecoderBatch  # no KV cache: the reference path
    monkeypatch.setenv("LWM_DECODING", "reference")
    assert type(make_decoder_batch(model)) is DecoderBatch
    with pytest.raises(ValueError):
        make_decoder_batch(model, "fastest")


def test_cross_attention_falls_back_to_the_reference_path():
    model = build_model("standard", PRESETS["tiny"]).eval()
    assert type(make_decoder_batch(model, "speculative")) is DecoderBatch


def test_the_flat_decoder_gives_the_reference_hidden_states_bit_for_bit(shipped, starts):
    # The first block in one call, then a token per call, as the flat path feeds them.
    model, manual = shipped
    n = len(starts)
    cond = condition_rows(model.condition_on(model.on_board(manual, board_of(starts))), n)
    reference_cache, flat = model.new_cache(n), FlatDecoder.for_model(model)
    rows = flat.new_cache(n)
    first = torch.from_numpy(first_block_tokens(starts))
    later = torch.from_numpy(np.concatenate([[0, 1], obs_to_tokens(starts[0]), [2, 0, 3]]))[None].repeat(n, 1)
    with torch.inference_mode():
        for tokens in [first] + [later[:, i : i + 1] for i in range(later.shape[1])]:
            reference = model.hidden_states(tokens, cond, reference_cache)
            mine = flat(tokens, rows, cond.id_table)
            rows.lengths += tokens.shape[1]
            assert torch.equal(mine, reference)


def test_the_flat_decoder_follows_the_weights():
    torch.manual_seed(0)
    model = build_model("observational", PRESETS["tiny"]).eval()
    first = FlatDecoder.for_model(model)
    assert FlatDecoder.for_model(model) is first
    with torch.no_grad():
        model.blocks[0].attn.qkv.weight.add_(1.0)
    assert FlatDecoder.for_model(model) is not first


def test_rows_of_different_lengths_attend_in_chunks_to_the_same_numbers(shipped, starts):
    # Requests that join a running batch share calls with rows far longer than theirs; the
    # attention then runs in chunks of rows at each chunk's own width (flat_decoder._chunks).
    model, manual = shipped
    n = len(starts)
    cond = condition_rows(model.condition_on(model.on_board(manual, board_of(starts))), n)
    flat = FlatDecoder.for_model(model)
    cache = flat.new_cache(n)
    everyone = torch.arange(n)
    tokens = torch.from_numpy(first_block_tokens(starts))
    later = torch.from_numpy(np.concatenate([[0, 1], obs_to_tokens(starts[0]), [2]]))[None]
    with torch.inference_mode():
        flat(tokens, cache, cond.id_table)
        cache.lengths += tokens.shape[1]
        old = everyone[: n // 2]  # the first half are older: 16 more steps each
        for _ in range(16):
            flat(later.repeat(len(old), 1), cache, None if cond.id_table is None else cond.id_table[old], rows=old)
            cache.lengths[old] += later.shape[1]
        step = _Step(model).eval()
        new = torch.tensor([[0, 3, 5, 20, 28]]).repeat(n, 1)
        last = cache.lengths + new.shape[1] - 1
        width = int(last.max()) + 1
        assert len(_chunks(last, width, new.shape[1], step.chunk_saving)) > 1
        k, v = cache.k.clone(), cache.v.clone()
        chunked = step(new, everyone, cache.lengths, cond.id_table, cache.k, cache.v)
        step.chunk_saving = 1 << 40  # one chunk at the call's widest
        whole = step(new, everyone, cache.lengths, cond.id_table, k, v)
    torch.testing.assert_close(chunked, whole, rtol=0, atol=1e-6)
    assert torch.equal(cache.k, k) and torch.equal(cache.v, v)


def test_the_row_cache_keeps_each_row_through_joins_and_leaves():
    torch.manual_seed(0)
    flat = FlatDecoder.for_model(build_model("observational", PRESETS["tiny"]).eval())
    cache, rows = flat.new_cache(0), []  # rows: (k, v) of each row held, up to its length

    def joining(count: int, length: int):
        other = flat.new_cache(count)
        other.k.normal_()
        other.v.normal_()
        other.lengths[:] = length
        return other, [(other.k[:, i, :, :length].clone(), other.v[:, i, :, :length].clone()) for i in range(count)]

    for count, length in [(3, 14), (2, 40), (40, 29)]:  # the last one outgrows the store
        other, held = joining(count, length)
        cache.extend(other)
        rows += held
    cache.select(torch.tensor([0, 4, 5, 44]))  # far fewer: the store shrinks
    rows = [rows[i] for i in (0, 4, 5, 44)]
    assert len(cache) == 4 and cache._k.shape[1] == 8
    other, held = joining(1, 20)
    cache.extend(other)
    rows += held
    cache.select(torch.tensor([4, 1, 3]))
    rows = [rows[i] for i in (4, 1, 3)]
    assert cache.lengths.tolist() == [20, 40, 29]
    for i, (k, v) in enumerate(rows):
        length = k.shape[2]
        assert torch.equal(cache.k[:, i, :, :length], k) and torch.equal(cache.v[:, i, :, :length], v)
