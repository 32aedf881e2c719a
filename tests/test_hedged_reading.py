"""Reading with hedges (lwm_models/world/hedged_reading.py), on the shipped checkpoint: the words
decide what they decide and leave the rest open; a reading the words agree with stands, one they
contradict becomes the mean prototype of what they allow; the shipped prototypes are what the
code fits from the weights they were made from."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from lwm_models.messenger.constants import ALL_TRIPLES
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.hedged_reading import candidates, hedge, words_code
from lwm_models.world.shipped import SHIPPED

HEDGED = "lwm_models/checkpoints/emma-lwm-hedged"


@pytest.fixture(scope="module")
def hedged():
    model, config = load_checkpoint(HEDGED, kind="emma-hedged")
    return model, config


def allowed(text: str) -> set[tuple[str, str, str]]:
    mask = candidates(torch.tensor(words_code(text)))
    return {ALL_TRIPLES[i] for i in torch.nonzero(mask).flatten().tolist()}


def test_the_words_decide_what_they_say_and_leave_the_rest_open():
    assert allowed("the plane chases you and it is deadly.") == {("airplane", "chaser", "enemy")}
    # No movement word: the three movements stay open, identity and role do not.
    assert allowed("the robot is the goal.") == {("robot", m, "goal") for m in ("chaser", "fleeing", "immovable")}
    # A negated role is no role: "not the goal" leaves the role open.
    assert {r for _, _, r in allowed("the ball never moves and it is not the goal.")} == {"enemy", "message", "goal"}


def test_a_reading_the_words_contradict_is_replaced_by_what_they_allow(hedged):
    model, _ = hedged
    pk, pv = model.proto_keys, model.proto_values
    a = ALL_TRIPLES.index(("airplane", "chaser", "enemy"))
    b = ALL_TRIPLES.index(("airplane", "chaser", "goal"))
    # Readings exactly at prototype a: words of a agree (the reading stands), words of b do not.
    keys, values = pk[a].expand(1, 2, -1).clone(), pv[a].expand(1, 2, -1).clone()
    codes = torch.tensor([[words_code("the plane chases you and it is deadly."),
                           words_code("the plane chases you and it is the goal.")]])  # fmt: skip
    k, v, stands = hedge(keys, values, codes, pk, pv, stand_distance=-1.0)  # none stands by nearness alone
    assert stands.tolist() == [[True, False]]
    assert torch.equal(k[0, 0], keys[0, 0]) and torch.equal(v[0, 0], values[0, 0])
    assert torch.allclose(k[0, 1], pk[b]) and torch.allclose(v[0, 1], pv[b])
    # Under the mean rule, a reading within the stand distance of a prototype stands whatever the
    # words say (the practised model's rule; the served mixture lets none stand by nearness).
    assert float(model.stand_distance) == 0.0
    _, _, stands = hedge(keys, values, codes, pk, pv, stand_distance=1.0)
    assert stands.all()
    # Words that leave the role open: the mean of the three roles' prototypes.
    open_role = [ALL_TRIPLES.index(("airplane", "chaser", r)) for r in ("enemy", "message", "goal")]
    far = torch.full_like(keys, 100.0)  # nearest to no candidate of these words
    codes = torch.tensor([[words_code("the plane chases you."), words_code("the plane chases you.")]])
    k, v, stands = hedge(far, far, codes, pk, pv)
    assert not stands.any() and torch.allclose(v[0, 0], pv[open_role].mean(0), atol=1e-6)


def test_the_dataset_s_kind_of_words_condition_as_the_reader_tuned_model_does(hedged):
    model, _ = hedged
    reader, _ = load_checkpoint(SHIPPED["emma-reader"], kind="emma")
    manual = ["the plane chases you and it is deadly.", "the ball has the message and runs away from you.",
              "the robot is the goal and it never moves."]  # fmt: skip
    encoder = model.frozen_text_encoder()
    with torch.no_grad():
        mine = model.condition(model.read_manual(manual, encoder)).id_table
        theirs = reader.condition(reader.read_manual(manual, encoder)).id_table
    assert torch.allclose(mine, theirs, atol=1e-5)


def test_the_shipped_prototypes_are_what_the_code_fits(hedged):
    model, config = hedged
    assert config["hedged_reading"]["source"].endswith("emma-lwm-reader")
    shipped_k, shipped_v = model.proto_keys.clone(), model.proto_values.clone()
    with torch.no_grad():
        model.fit_prototypes(model.frozen_text_encoder(), seed=config["hedged_reading"]["seed"])
    # The checkpoint is fp16: the fit from its (fp16) weights matches to fp16's precision.
    assert torch.allclose(model.proto_keys, shipped_k, atol=2e-2, rtol=1e-2)
    assert torch.allclose(model.proto_values, shipped_v, atol=2e-3, rtol=1e-2)
    model.proto_keys.copy_(shipped_k)
    model.proto_values.copy_(shipped_v)


def test_the_server_says_what_the_words_leave_open_and_whether_the_model_guessed():
    from lwm_models.world.frozen_text import FrozenTextEncoder
    from lwm_models.world.model_server import WorldModelServer

    board_manual = ["the plane chases you and it is deadly.", "the ball has the message and flees.",
                    "the robot is the goal and it never moves."]  # fmt: skip
    person = ["the plane chases you and it is deadly.", "the ball has the message and flees.",
              "the thing that stays put is not the goal."]  # fmt: skip
    notes = {}
    for name in ("emma-lwm-hedged", "emma-lwm-reader"):
        srv = WorldModelServer(checkpoint=f"lwm_models/checkpoints/{name}", encoder=FrozenTextEncoder())
        srv.take_env_manual(board_manual, "newall-test:0:0")
        assert srv.ungrounded() is None  # every fact said, every entity on the board
        srv.set_manual(person, "human")
        notes[name] = (srv.status()["reading"], srv.ungrounded())
    reading, note = notes["emma-lwm-hedged"]
    assert "unsure" not in reading[0] and "unsure" not in reading[1]
    # "not the goal" says no role: the hedged model names what is open, and the person hears it.
    assert reading[2]["unsure"] == ["role"] and isinstance(reading[2]["guessed"], bool)
    assert '"the thing that stays put is not the goal." leaves its role unclear' in note
    # A model that does not check its reading against the words always guesses; the person still
    # hears which fact no keyword states.
    reading, note = notes["emma-lwm-reader"]
    assert reading[2]["unsure"] == ["role"] and reading[2]["guessed"] is True
    assert '"the thing that stays put is not the goal." leaves its role unclear (the world model guessed)' in note


def test_hedge_practice_opens_fields_of_the_words_and_hedges_only_what_it_picked():
    from lwm_models.world.hedged_reading import practice_codes

    torch.manual_seed(0)
    codes = torch.tensor([[words_code("the plane chases you and it is deadly.")] * 3] * 400)
    same, force = practice_codes(codes, 0.0)
    assert torch.equal(same, codes) and not force.any()
    practised, force = practice_codes(codes, 0.5)
    assert 0.4 < force.float().mean() < 0.6
    assert torch.equal(practised[~force], codes[~force])  # unpicked descriptions keep their words
    assert torch.equal(practised // 16, codes // 16)  # the identity is never opened
    opened_movement = (practised // 4) % 4 == 0
    opened_role = practised % 4 == 0
    assert 0.35 < opened_movement[force].float().mean() < 0.65 and 0.35 < opened_role[force].float().mean() < 0.65
    # what the practice hedges is exactly the mean prototype of what its words allow
    model, _ = load_checkpoint(HEDGED, kind="emma-hedged")
    pk, pv = model.proto_keys, model.proto_values
    keys, values = pk[0].expand(400, 3, -1).clone(), pv[0].expand(400, 3, -1).clone()
    k, _, stands = hedge(keys, values, practised, pk, pv, stand_distance=1e9, force=force)
    assert torch.equal(stands, ~force)
    i, j = map(int, torch.nonzero(force & opened_role & ~opened_movement)[0])
    assert torch.allclose(k[i, j], pk[candidates(practised[i, j])].mean(0), atol=1e-6)


def test_hedge_practice_trains_the_decoder_and_leaves_the_reader_alone(tmp_path, capsys, monkeypatch):
    from lwm_models.cli import main as cli_main

    model, _ = load_checkpoint(HEDGED, kind="emma-hedged")
    model.practise_hedges(1.0)
    frozen = [n for n, p in model.named_parameters() if not p.requires_grad]
    trained = [n for n, p in model.named_parameters() if p.requires_grad]
    assert any(n.startswith("text_encoder.") for n in frozen) and "reader.k.weight" in frozen
    assert "reader.q.weight" in trained and any(n.startswith("obs_head") for n in trained)
    manual = ["the plane chases you and it is deadly.", "the ball has the message and runs away from you.",
              "the robot is the goal and it never moves."]  # fmt: skip
    batch = model.read_manual(manual, model.frozen_text_encoder())
    with torch.no_grad():
        model.eval()
        read = model.condition(batch).id_table
        model.train()
        practised = model.condition(batch).id_table
    assert not torch.allclose(read, practised), "every description was to be hedged in training"
    # a model that cannot hedge refuses the option in words (in this process: `lwm train` would
    # otherwise re-execute itself with the allocator's tunables, replacing the test's process)
    monkeypatch.setenv("LWM_NO_ALLOCATOR_TUNING", "1")
    code = cli_main.main(["train", "--kind", "emma", "--data", str(tmp_path), "--out", str(tmp_path / "run"),
                          "--hedge-practice", "0.5", "--steps", "1"])  # fmt: skip
    assert code != 0 and "needs a hedged world model" in capsys.readouterr().err


# ---------------------------------------------------------------- reading every way the words allow


def test_readings_are_the_model_s_own_where_the_words_decide_and_each_possibility_elsewhere(hedged):
    from lwm_models.world.hedged_reading import OWN_WEIGHT, readings

    model, _ = hedged
    pk, pv = model.proto_keys, model.proto_values
    a = ALL_TRIPLES.index(("airplane", "chaser", "enemy"))
    keys, values = pk[a].expand(1, 3, -1).clone(), pv[a].expand(1, 3, -1).clone()
    # all decided and the model agrees: one reading; movement open, the model's reading among those
    # allowed; the model's reading excluded by the words
    words = ["the plane chases you and it is deadly.", "the plane is deadly.",
             "the plane chases you and it is the goal."]  # fmt: skip
    codes = torch.tensor([[words_code(w) for w in words]])
    r = readings(keys, values, codes, pk, pv, stand_distance=-1.0, doubt=0.0)
    assert r.alone.tolist() == [[True, False, False]] and r.own_among.tolist() == [[False, True, False]]
    # 1 x 3 x 1 combinations, likeliest first: the model's own reading of the second description
    assert len(r.owner) == 3 and r.owner.tolist() == [0, 0, 0]
    assert torch.allclose(r.log_prior.exp(), torch.tensor([OWN_WEIGHT, 0.1, 0.1]), atol=1e-6)
    assert torch.equal(r.keys[:, 0], keys[0, 0].expand(3, -1))  # the first description: always its own
    assert torch.equal(r.keys[0, 1], keys[0, 1])  # the likeliest reading is the model's own
    second = {ALL_TRIPLES.index(("airplane", m, "enemy")) for m in ("fleeing", "immovable")}
    assert {int(hedge_index(pk, r.keys[i, 1])) for i in (1, 2)} == second
    # the third description is read as the one triple its words allow, in every combination
    b = ALL_TRIPLES.index(("airplane", "chaser", "goal"))
    assert all(torch.equal(r.keys[i, 2], pk[b]) for i in range(3))
    # with a stand distance (none in the served model), a reading that near a prototype stands
    # alone, unless the words state movement and role against it
    assert readings(keys, values, codes, pk, pv, stand_distance=1.0).alone.tolist() == [[True, True, False]]


def test_where_the_words_name_another_entity_the_model_s_entity_stays_possible(hedged):
    from lwm_models.world.hedged_reading import OTHER_IDENTITY, readings

    model, _ = hedged
    pk, pv = model.proto_keys, model.proto_values
    ball = ALL_TRIPLES.index(("ball", "chaser", "enemy"))
    plane = ALL_TRIPLES.index(("airplane", "chaser", "enemy"))
    keys, values = pk[ball].expand(1, 3, -1).clone(), pv[ball].expand(1, 3, -1).clone()  # read as the ball
    codes = torch.tensor([[words_code("the plane chases you and it is deadly.")] * 3])  # the words: the plane
    r = readings(keys[:, :1], values[:, :1], codes[:, :1], pk, pv, stand_distance=-1.0, doubt=0.0)
    assert len(r.owner) == 2 and not r.alone.any()
    assert torch.equal(r.keys[0, 0], pk[plane]) and torch.equal(r.keys[1, 0], keys[0, 0])
    assert torch.allclose(r.log_prior.exp(), torch.tensor([1 - OTHER_IDENTITY, OTHER_IDENTITY]))
    # without it, the words' entity alone
    alone = readings(keys[:, :1], values[:, :1], codes[:, :1], pk, pv, -1.0, other_identity=0.0, doubt=0.0)
    assert len(alone.owner) == 1


def hedge_index(proto_keys: torch.Tensor, key: torch.Tensor) -> int:
    return int((proto_keys - key).abs().sum(-1).argmin())


def test_a_manual_with_many_open_fields_keeps_its_likeliest_readings(hedged):
    from lwm_models.world.hedged_reading import MAX_READINGS, readings

    model, _ = hedged
    far = torch.full((2, 3, model.proto_keys.shape[1]), 100.0)  # near no prototype: no own reading
    codes = torch.tensor([[words_code("the plane.")] * 3, [words_code("the plane chases you and it is deadly.")] * 3])
    r = readings(far, far, codes, model.proto_keys, model.proto_values, other_identity=0.0, doubt=0.0)
    # 9 x 9 x 9 equally likely combinations for the first manual, kept to the cap; one for the second
    assert r.owner.tolist() == [0] * MAX_READINGS + [1]
    assert torch.allclose(r.log_prior[:MAX_READINGS].exp().sum(), torch.tensor(1.0))
    assert float(r.log_prior[-1]) == 0.0


def test_the_mixture_is_bayes_rule_over_the_readings():
    from lwm_models.world.hedged_reading import mixture_log_probs

    # two readings of one manual, two binary tokens at positions 0 and 1 (kinds "a" and "b")
    p = torch.tensor([[[0.9, 0.1], [0.5, 0.5]], [[0.2, 0.8], [0.3, 0.7]]])  # [R, P, V]: reading r, token t
    prior = torch.tensor([0.25, 0.75])
    log_probs = {"a": p[:, :1].log(), "b": p[:, 1:].log()}
    targets = {"a": torch.tensor([[0], [0]]), "b": torch.tensor([[1], [1]])}
    positions = {"a": torch.tensor([0]), "b": torch.tensor([1])}
    out = mixture_log_probs(log_probs, targets, positions, torch.tensor([0, 0]), prior.log())
    # the first token: the prior mixture; the second: the posterior after seeing token 0 = 0
    first = prior[0] * p[0, 0] + prior[1] * p[1, 0]
    post = prior * torch.tensor([0.9, 0.2])
    post = post / post.sum()
    second = post[0] * p[0, 1] + post[1] * p[1, 1]
    assert torch.allclose(out["a"][0, 0].exp(), first) and torch.allclose(out["b"][0, 0].exp(), second)
    # one reading: its own predictions
    one = mixture_log_probs(
        {k: v[:1] for k, v in log_probs.items()},
        {k: v[:1] for k, v in targets.items()},
        positions,
        torch.tensor([0]),
        torch.zeros(1),
    )
    assert torch.allclose(one["b"], log_probs["b"][:1])


def test_trajectories_of_one_manual_imagine_its_readings_in_proportion(hedged):
    from lwm_models.world.base import Conditioning
    from lwm_models.world.imagine import condition_rows

    owner = torch.tensor([0, 0, 0])
    table = torch.arange(3.0).view(3, 1, 1).expand(3, 17, 4)
    cond = Conditioning(id_table=table, reading_owner=owner, reading_log_prior=torch.tensor([0.8, 0.1, 0.1]).log())
    picked = condition_rows(cond, 10).id_table[:, 0, 0].tolist()
    assert sorted(picked) == [0.0] * 8 + [1.0, 2.0]
    assert condition_rows(cond, 1).id_table[:, 0, 0].tolist() == [0.0]  # alone: the likeliest
    # one manual per trajectory: each row reads its own manual's readings
    two = Conditioning(id_table=table[:2], reading_owner=torch.tensor([0, 1]), reading_log_prior=torch.zeros(2))
    assert condition_rows(two, 2).id_table[:, 0, 0].tolist() == [0.0, 1.0]

    # the shipped model: a manual whose words leave movements open imagines several futures
    model, _ = hedged
    manual = ["the plane is deadly.", "the ball has the message.", "the robot is the goal."]
    cond = model.condition_on(model.read_manual(manual, model.frozen_text_encoder()))
    assert cond.reading_owner is not None and len(cond.reading_owner) > 1
    rows = condition_rows(cond, 32).id_table
    assert len({tuple(t.flatten()[:8].tolist()) for t in rows}) > 1
    # with the mixture off, the mean prototype as before: one row
    model.mixture = False
    try:
        assert model.condition_on(model.read_manual(manual, model.frozen_text_encoder())).reading_owner is None
    finally:
        model.mixture = True


def test_reading_each_possibility_predicts_episodes_better_than_the_mean_prototype(hedged, tmp_path):
    from lwm_models.data.dataset import generate_dataset
    from lwm_models.messenger.constants import SPLITS
    from lwm_models.text.pools import DescriptionPools
    from lwm_models.world.train import evaluate_loss
    from lwm_models.world.training_data import SplitTokens, redraw_manuals

    model, _ = hedged
    generate_dataset(tmp_path, DescriptionPools.generated(), max_games=12, train_episodes_per_game=2,
                     splits=("newall-dev",))  # fmt: skip
    encoder = model.frozen_text_encoder()
    data = SplitTokens(tmp_path, "newall-dev", encoder, model.route)
    # Manuals that say who is what but not how it moves: the mean prototype averages the three
    # movements, the mixture imagines each.
    unsaid = {t: (f"you will find the {t[0]} here, it is the {t[2]}.",) for t in ALL_TRIPLES}
    redraw_manuals(data, DescriptionPools({split: dict(unsaid) for split in SPLITS}, "movement unsaid"), encoder, 0)
    data.routed = torch.tensor([model.route(t, encoder) for t in data.texts]).numpy()
    mixed = evaluate_loss(model, data, limit=24)["total"]
    model.mixture = False
    try:
        mean = evaluate_loss(model, data, limit=24)["total"]
    finally:
        model.mixture = True
    assert mixed < mean - 0.02, (mixed, mean)


def test_each_shipped_hedged_checkpoint_reads_with_the_rule_it_was_measured_with(hedged):
    model, config = hedged
    assert config["hedged_reading"]["rule"] == "mixture" and model.mixture
    practised, config = load_checkpoint("lwm_models/checkpoints/emma-lwm-practised", kind="emma-hedged")
    assert config["hedged_reading"]["rule"] == "mean" and not practised.mixture
    batch = practised.read_manual(["the plane is deadly."] * 3, practised.frozen_text_encoder())
    assert practised.condition_on(batch).reading_owner is None  # one row: the mean prototype


def test_the_rules_benchmark_refuses_what_it_cannot_compare(capsys):
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("hedged_rules", Path("benchmarks/hedged_rules.py"))
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--data", "data/none", "--split", "newall-test"]) == 2
    assert "chosen on dev splits" in capsys.readouterr().err
    assert bench.main(["--data", "data/none", "--rules", "mixture:2"]) == 2
    assert "must be in (0, 1]" in capsys.readouterr().err
    assert bench.main(["--data", "data/none", "--rules", "mixture:0.8:1"]) == 2
    assert "[0, 1)" in capsys.readouterr().err
    assert bench.main(["--data", "data/none", "--rules", "mixture:0.8:0.15:0.05:2.5"]) == 2
    assert "whole number" in capsys.readouterr().err
    assert bench.main(["--data", "data/none", "--rules", "median"]) == 2
    assert "unknown rule 'median'" in capsys.readouterr().err
    gpthard = "lwm_models/checkpoints/gpthard"
    assert bench.main(["--data", "data/none", "--checkpoint", gpthard + "-hedged", "--rules", "mean"]) == 2
    assert "no mean-prototype rule" in capsys.readouterr().err
    assert bench.main(["--data", "data/none", "--checkpoint", gpthard]) == 2
    assert "not a hedged one" in capsys.readouterr().err


def test_words_naming_an_entity_off_the_board_are_grounded_on_it():
    from lwm_models.messenger.constants import IDENTITIES
    from lwm_models.world.hedged_reading import ground_words

    plane, ball, robot, queen, dog = (IDENTITIES[n] for n in ("airplane", "ball", "robot", "queen", "dog"))
    words = [words_code("the plane chases you and it is deadly."), words_code("the ball is the goal."),
             words_code("the queen has the message.")]  # fmt: skip
    codes = torch.tensor([words])

    def sets(among):
        return [sorted(torch.nonzero(a).flatten().tolist()) if not a.all() else "any" for a in among[0]]

    grounded, among = ground_words(codes, torch.tensor([[plane, ball, robot]]))
    # the queen is not on the board; the robot is the one entity no other description names
    assert (grounded // 16).tolist() == [[plane, ball, robot]] and sets(among) == ["any", "any", [robot]]
    assert torch.equal(grounded % 16, codes % 16)  # movement and role as the words say
    # two descriptions off the board, two board entities left: each is one of them
    grounded, among = ground_words(codes, torch.tensor([[plane, dog, robot]]))
    assert (grounded // 16).tolist() == [[plane, 0, 0]] and sets(among) == ["any", [dog, robot], [dog, robot]]
    # two descriptions naming the same board entity: one of them is about the entity no one names
    twice = torch.tensor([[words[0], words[0], words[1]]])
    grounded, among = ground_words(twice, torch.tensor([[plane, ball, robot]]))
    assert (grounded // 16).tolist() == [[0, 0, ball]] and sets(among) == [[plane, robot], [plane, robot], "any"]
    # more descriptions off the board than entities left: open, as any entity
    grounded, among = ground_words(codes, torch.tensor([[plane, 0, robot]]))
    assert (grounded // 16).tolist() == [[plane, 0, 0]] and sets(among) == ["any", "any", "any"]
    # every description on the board: unchanged
    grounded, among = ground_words(codes, torch.tensor([[plane, ball, queen]]))
    assert torch.equal(grounded, codes) and bool(among.all())


def test_descriptions_left_to_the_same_board_entities_are_read_as_different_ones(hedged):
    from lwm_models.messenger.constants import IDENTITIES
    from lwm_models.world.hedged_reading import _TRIPLE_FIELDS, ground_words, prototype_distances, readings

    model, _ = hedged
    pk, pv = model.proto_keys, model.proto_values
    plane, dog, robot = (IDENTITIES[n] for n in ("airplane", "dog", "robot"))
    # the model reads all three as the plane chasing you and deadly; the words name the plane
    # once and then two entities off the board, whose movement and role they state
    a = ALL_TRIPLES.index(("airplane", "chaser", "enemy"))
    keys, values = pk[a].expand(1, 3, -1).clone(), pv[a].expand(1, 3, -1).clone()
    codes = torch.tensor([[words_code("the plane chases you and it is deadly."),
                           words_code("the queen never moves and has the message."),
                           words_code("the wizard never moves and is the goal.")]])  # fmt: skip
    grounded, among = ground_words(codes, torch.tensor([[plane, dog, robot]]))
    r = readings(keys, values, grounded, pk, pv, stand_distance=1.0, among=among, doubt=0.0)
    # nearness does not let a reading of an entity the board rules out stand
    assert r.alone.tolist() == [[True, False, False]]
    entity = _TRIPLE_FIELDS[prototype_distances(r.keys, r.values, pk, pv).argmin(-1), 0]  # [R, 3]
    # two readings, the dog and the robot each way round, and never the same entity twice
    assert sorted(entity[:, 1:].tolist()) == [[dog, robot], [robot, dog]]
    assert torch.allclose(r.log_prior.exp(), torch.tensor([0.5, 0.5]))


def test_a_hedged_model_grounds_its_words_only_when_its_config_says_so(hedged, tmp_path):
    from lwm_models.data.dataset import generate_dataset
    from lwm_models.text.pools import DescriptionPools
    from lwm_models.text.stress import stress_pools
    from lwm_models.world.base import ManualBatch
    from lwm_models.world.hedged_reading import ground_words
    from lwm_models.world.tokens import ID_SLOTS
    from lwm_models.world.training_data import SplitTokens, redraw_manuals

    model, config = hedged
    assert model.ground is bool(config["hedged_reading"].get("ground", False))
    board = torch.tensor([[2, 3, 5]])
    manual = ManualBatch(routed=torch.tensor([[7 * 16 + 5, 3 * 16 + 6, 2 * 16 + 9]]))
    saved = model.ground
    try:
        model.ground = False
        assert model.on_board(manual, board) is manual
        model.ground = True
        assert (model.on_board(manual, board).routed // 16).tolist() == [[5, 3, 2]]
        assert model.on_board(manual, board).among is not None
        # teacher-forced, the board is each episode's first observation: exactly the episodes
        # whose words name an entity off their board are predicted otherwise
        generate_dataset(tmp_path, DescriptionPools.generated(), max_games=12, train_episodes_per_game=2,
                         splits=("newall-dev",))  # fmt: skip
        encoder = model.frozen_text_encoder()
        data = SplitTokens(tmp_path, "newall-dev", encoder, model.route)
        redraw_manuals(data, stress_pools("rare-synonyms", "dev"), encoder, 0)  # names guessed wrongly
        tokens, lengths, episodes = next(iter(data.full_episodes(24, 24)))
        grounded, among = ground_words(episodes.routed, tokens[:, torch.as_tensor(ID_SLOTS)])
        changed = (grounded != episodes.routed).any(-1) | ~among.flatten(1).all(-1)
        assert changed.any() and not changed.all()
        obs = {}
        for ground in (False, True):
            model.ground = ground
            with torch.no_grad():
                obs[ground] = model.predictions(tokens, lengths, episodes)["obs"][0]
        differs = (obs[True] - obs[False]).abs().flatten(1).amax(1) > 1e-6
        assert torch.equal(differs, changed)
    finally:
        model.ground = saved


def test_the_server_conditions_on_the_words_as_grounded_and_computes_them_once(hedged):
    from lwm_models.messenger.constants import IDENTITIES
    from lwm_models.world.frozen_text import FrozenTextEncoder
    from lwm_models.world.model_server import WorldModelServer

    plane, ball, robot, queen = (IDENTITIES[n] for n in ("airplane", "ball", "robot", "queen"))
    own_board, other_board = torch.tensor([[plane, ball, robot]]), torch.tensor([[plane, ball, queen]])
    srv = WorldModelServer(checkpoint=HEDGED, encoder=FrozenTextEncoder())
    srv.set_manual(["the plane chases you and it is deadly.", "the ball has the message.", "the robot is the goal."])
    state = srv.state()
    # the manual's reading is of one board: computed once for it, anew for another board
    read = srv._conditioning(state.batch, state, own_board)
    assert srv._conditioning(state.batch, state, own_board) is read
    assert srv._conditioning(state.batch, state, other_board) is not read
    # without a reading, a model that does not ground reads the manual the same on any board
    calibration, srv.model.reading_calibration = srv.model.reading_calibration, None
    state.batch = srv.model.read_manual(state.manual, srv.encoder)
    srv.model.ground = False
    first = srv._conditioning(state.batch, state, own_board)
    assert srv._conditioning(state.batch, state, other_board) is first
    srv.model.ground = True
    try:
        on_own = srv._conditioning(state.batch, state, own_board)
        assert srv._conditioning(state.batch, state, own_board) is on_own  # the same words: once
        # on a board without the robot, the goal is the queen: other words, conditioned anew
        on_other = srv._conditioning(state.batch, state, other_board)
        assert on_other is not on_own and [w // 16 for w in state.cond_words[:3]] == [plane, ball, queen]
    finally:
        srv.model.ground = False
        srv.model.reading_calibration = calibration


def _generated_episodes(model, tmp_path):
    """8 NewAll-dev episodes of a small generated dataset, as (tokens, lengths, manuals)."""
    from lwm_models.data.dataset import generate_dataset
    from lwm_models.text.pools import DescriptionPools
    from lwm_models.world.training_data import SplitTokens

    generate_dataset(tmp_path, DescriptionPools.generated(), max_games=8, train_episodes_per_game=2,
                     splits=("newall-dev",))  # fmt: skip
    data = SplitTokens(tmp_path, "newall-dev", model.frozen_text_encoder(), model.route)
    return next(iter(data.full_episodes(8, 8)))


def test_doubt_keeps_the_truth_among_the_readings_where_the_words_decide_a_field_wrongly(hedged, tmp_path):
    import math

    model, _ = hedged
    tokens, lengths, episodes = _generated_episodes(model, tmp_path)
    roles = episodes.routed % 4
    assert bool((roles > 0).all())  # the generator's words decide every role
    wrong = replace(episodes, routed=episodes.routed.clone())
    wrong.routed[:, 0] += roles[:, 0] % 3 + 1 - roles[:, 0]  # the first description's role: another one

    def nll(manual, doubt: float) -> torch.Tensor:
        """Each episode's negative log-likelihood under the readings' mixture [B]."""
        saved = model.doubt
        model.doubt = doubt
        try:
            with torch.no_grad():
                out = model.predictions(tokens, lengths, manual)
        finally:
            model.doubt = saved
        total = 0
        for log_probs, targets, valid in out.values():
            total = total - (log_probs.gather(-1, targets[..., None]).squeeze(-1) * valid).sum(1)
        return total

    # words that state the wrong role: without doubt the truth is no reading; with it, an episode
    # that meets the entity soon shows which reading is right
    doubting, sure = nll(wrong, 0.02), nll(wrong, 0.0)
    assert float(doubting.sum()) < float(sure.sum()) - 10
    # an episode costs at most what the doubt takes from its readings' prior (Bayes), right words or not
    bound = -3 * math.log(1 - 0.02) + 1e-3
    assert bool((doubting <= sure + bound).all())
    assert bool((nll(episodes, 0.02) <= nll(episodes, 0.0) + bound).all())


def test_more_readings_keep_the_truth_where_the_words_state_two_movements_wrongly(hedged, tmp_path):
    from lwm_models.world.base import _targets_layout
    from lwm_models.world.hedged_reading import PRUNE_STEPS
    from lwm_models.world.tokens import BLOCK, SLOT_DONE, SLOT_OBS, SLOT_REWARD

    model, _ = hedged
    tokens, lengths, episodes = _generated_episodes(model, tmp_path)
    moves = (episodes.routed // 4) % 4
    assert bool((moves > 0).all())  # the generator's words decide every movement
    wrong = replace(episodes, routed=episodes.routed.clone())
    wrong.routed[:, :2] += (moves[:, :2] % 3 + 1 - moves[:, :2]) * 4  # two descriptions' movements: others

    def predict(most: int, keep: int = 0) -> dict:
        saved = model.doubt, model.max_readings, model.keep_readings
        model.doubt, model.max_readings, model.keep_readings = 0.05, most, keep
        try:
            with torch.no_grad():
                return model.predictions(tokens, lengths, wrong)
        finally:
            model.doubt, model.max_readings, model.keep_readings = saved

    def nll(out: dict) -> torch.Tensor:
        return -sum((lp.gather(-1, t[..., None]).squeeze(-1) * v).sum(1) for lp, t, v in out.values())

    # Each of the three descriptions has 5 readings (its words and 4 one field away): 125 in all.
    # Among the 27 likeliest, a manual with two stated movements wrong seldom holds the truth.
    few, every = nll(predict(27)), predict(125)
    assert float(nll(every).sum()) < float(few.sum()) - 10
    # More readings cost at most the prior the 27 lose to the others (about 1.5% of it here).
    assert bool((nll(every) <= few + 0.05).all())
    # The first steps show the movements: 9 readings kept after them predict the rest almost as
    # all 125 do, and the first steps' predictions are all 125 readings' mixture (a pass over the
    # first steps alone).
    pruned = predict(125, keep=9)
    assert bool((nll(pruned) <= nll(every) + 0.05).all())
    early = (1 + PRUNE_STEPS) * BLOCK
    for kind, (lp, _, _) in pruned.items():
        slot = {"obs": SLOT_OBS, "reward": SLOT_REWARD, "done": SLOT_DONE}[kind]
        n = int((_targets_layout(tokens.shape[1])[slot] + 1 < early).sum())
        assert torch.allclose(lp[:, :n], every[kind][0][:, :n], atol=1e-4)  # a shorter pass's rounding
