"""Reading with hedges (lwm_models/world/hedged_reading.py), on the shipped checkpoint: the words
decide what they decide and leave the rest open; a reading the words agree with stands, one they
contradict becomes the mean prototype of what they allow; the shipped prototypes are what the
code fits from the weights they were made from."""

from __future__ import annotations

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
    # A reading as near a prototype as the dataset's own text is read stands whatever the words say.
    assert 0 < float(model.stand_distance) < 10
    _, _, stands = hedge(keys, values, codes, pk, pv, model.stand_distance)
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
