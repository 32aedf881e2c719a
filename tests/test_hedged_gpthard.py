"""GPTHard reading with hedges (lwm_models/world/hedged_gpthard.py), on the shipped checkpoints: its
weights are GPTHard's, a reading's value goes to the entity its routing names, a description whose
words name no entity is hedged over the entities, and on free-form manuals it predicts episodes
better than GPTHard reading them as it was trained to."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lwm_models.messenger.constants import ALL_TRIPLES, IDENTITIES, NUM_IDS
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.hedged_gpthard import routing_keys
from lwm_models.world.hedged_reading import Readings, code_fields, readings, words_code
from lwm_models.world.shipped import SHIPPED


@pytest.fixture(scope="module")
def models():
    hedged, config = load_checkpoint(SHIPPED["gpthard-hedged"], kind="gpthard-hedged")
    plain, _ = load_checkpoint(SHIPPED["gpthard"], kind="gpthard")
    return hedged, plain, config


def test_the_weights_are_gpthard_s_and_the_prototypes_what_the_code_fits(models):
    hedged, plain, config = models
    mine = hedged.state_dict()
    for name, tensor in plain.state_dict().items():
        assert torch.equal(mine[name], tensor), name
    assert config["hedged_reading"]["source"].endswith("checkpoints/gpthard")
    assert float(hedged.stand_distance) == 0.0 and hedged.other_identity == 0.0 and hedged.mixture
    shipped_k, shipped_v = hedged.proto_keys.clone(), hedged.proto_values.clone()
    # a prototype's routing is its triple's entity
    identities = torch.tensor([IDENTITIES[i] for i, _, _ in ALL_TRIPLES])
    assert torch.equal(shipped_k.argmax(-1), identities)
    with torch.no_grad():
        hedged.fit_prototypes(hedged.frozen_text_encoder(), seed=config["hedged_reading"]["seed"])
    try:
        assert torch.allclose(hedged.proto_keys, shipped_k, atol=1e-3)
        assert torch.allclose(hedged.proto_values, shipped_v, atol=2e-3, rtol=1e-2)
    finally:
        hedged.proto_keys.copy_(shipped_k)
        hedged.proto_values.copy_(shipped_v)


def test_a_reading_s_value_goes_to_the_entity_its_routing_names(models):
    hedged, _, _ = models
    width = hedged.proto_values.shape[1]
    plane, ball = IDENTITIES["airplane"], IDENTITIES["ball"]
    keys = routing_keys(torch.tensor([[plane, ball, 0]]))
    values = torch.stack([torch.full((width,), float(i + 1)) for i in range(3)])[None]
    r = Readings(keys, values, torch.tensor([0]), torch.zeros(1), torch.ones(1, 3, dtype=torch.bool),
                 torch.zeros(1, 3, dtype=torch.bool))  # fmt: skip
    table = hedged._tables(r)[0]
    assert torch.equal(table[plane], values[0, 0]) and torch.equal(table[ball], values[0, 1])
    others = [i for i in range(NUM_IDS) if i not in (plane, ball)]
    assert not table[others].any()  # unrouted: conditions nothing


def test_words_that_name_no_entity_are_hedged_over_the_entities(models):
    hedged, _, _ = models
    unnamed = words_code("the plane chases you and it is the goal.") % 16  # the same words naming no entity
    codes = torch.tensor([[words_code("the plane chases you and it is deadly."), unnamed]])
    keys = routing_keys(codes // 16)
    values = hedged.proto_values[[ALL_TRIPLES.index(("airplane", "chaser", "enemy"))] * 2][None]
    r = readings(keys, values, codes, hedged.proto_keys, hedged.proto_values, 0.0, other_identity=0.0, doubt=0.0)
    routed = {int(i) for i in hedged._tables(r).abs().sum(-1).nonzero()[:, 1].tolist()}
    assert IDENTITIES["airplane"] in routed and len(routed) > 2  # the goal is read as several entities
    assert len(r.owner) > 1


def test_the_read_back_names_the_entity_the_words_route_to(models):
    from lwm_models.world.reading import read_identities

    hedged, plain, _ = models
    texts = ["the plane chases you and it is deadly.", "the hound is the goal.", "it never moves."]
    read = read_identities(hedged, hedged.frozen_text_encoder(), texts)
    assert read[:2] == ["airplane", "dog"]
    # no name at all: the encoder's nearest name routes it, and the read-back says which
    assert IDENTITIES[read[2]] == int(code_fields(torch.tensor(words_code(texts[2])))[0])
    assert read_identities(plain, plain.frozen_text_encoder(), texts)[:2] == ["airplane", "dog"]


def test_hedged_gpthard_predicts_free_form_episodes_better_than_gpthard(models, tmp_path):
    from lwm_models.data.dataset import generate_dataset
    from lwm_models.text.pools import DescriptionPools
    from lwm_models.text.stress import stress_pools
    from lwm_models.world.train import evaluate_loss
    from lwm_models.world.training_data import SplitTokens, redraw_manuals

    hedged, plain, _ = models
    generate_dataset(tmp_path, DescriptionPools.generated(), max_games=12, train_episodes_per_game=2,
                     splits=("newall-dev",))  # fmt: skip
    encoder = hedged.frozen_text_encoder()
    loss = {}
    for model in (hedged, plain):
        data = SplitTokens(tmp_path, "newall-dev", encoder, model.route)
        redraw_manuals(data, stress_pools("casual", "dev"), encoder, 0)
        loss[model.kind] = evaluate_loss(model, data, limit=24)["total"]
    assert loss["gpthard-hedged"] < loss["gpthard"] - 0.05, loss


def test_hedged_gpthard_imagines_each_possibility_on_the_fast_path(models):
    from lwm_models.data.splits import load_split
    from lwm_models.messenger.engine import BatchedMessenger
    from lwm_models.world.imagine import imagine

    hedged, _, _ = models
    game = load_split("newall-test")[0]
    engine = BatchedMessenger()
    engine.reset([game], [0])
    first = engine.compact_observation()[0]
    manual = hedged.read_manual(["the plane is deadly.", "the ball has the message.", "the robot is the goal."],
                                hedged.frozen_text_encoder())  # fmt: skip
    assert len(hedged.condition_on(manual).reading_owner) > 1  # movements left open
    actions = np.random.default_rng(0).integers(5, size=(8, 6))
    runs = [imagine(hedged, manual, first, n=8, actions=actions, max_steps=6, seed=0, stop_on_done=False,
                    decoding=path) for path in ("reference", "speculative")]  # fmt: skip
    assert np.array_equal(runs[0].observations, runs[1].observations)
