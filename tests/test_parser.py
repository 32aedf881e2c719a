"""The offline keyword parser that routes descriptions for GPTHard."""

from __future__ import annotations

from pathlib import Path

import pytest

from lwm_models.messenger.constants import ALL_TRIPLES, IDENTITIES
from lwm_models.text import generate_descriptions, load_description_file
from lwm_models.text.parser import (
    normalise,
    parse_description,
    parse_movement,
    parse_role,
    parser_accuracy,
    route_identity_id,
)
from lwm_models.text.stress import stress_texts

VAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "messenger-texts" / "text_val.json"


def test_generated_descriptions_parse_back_to_their_triple():
    texts = {t: generate_descriptions(t) for t in ALL_TRIPLES}
    acc = parser_accuracy(texts)
    # The project's own phrasings are read exactly: the demo's default manuals are generated.
    assert (acc["identity"], acc["movement"], acc["role"]) == (1.0, 1.0, 1.0), acc


@pytest.mark.parametrize(
    "text, expected",
    [
        ("the falcon that never moves is the deadly enemy.", ("bird", "immovable", "enemy")),
        ("the scholar running away from you holds the secret document.", ("scientist", "fleeing", "message")),
        ("the humanoid coming toward you is the goal.", ("robot", "chaser", "goal")),
        ("an unmoving jet has the classified note.", ("airplane", "immovable", "message")),
    ],
)
def test_examples(text, expected):
    assert parse_description(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        # a negated role rules that role out; the positive cue elsewhere decides
        ("the hound is not the goal; it holds the message and stays put.", ("dog", "immovable", "message")),
        ("not an enemy: the queen chases you, she is the destination.", ("queen", "chaser", "goal")),
        ("the robot isn't the message, it runs away and it is deadly.", ("robot", "fleeing", "enemy")),
        # two negated roles leave the third
        ("the sword is neither the enemy nor the goal, and it never moves.", ("sword", "immovable", "message")),
        ("the ball isn't an enemy and isn't the goal. it flees.", ("ball", "fleeing", "message")),
        # negated motion: "doesn't move" is immovable, a negated chase is not a chase
        ("the ship doesn't move and is the enemy.", ("ship", "immovable", "enemy")),
        ("the mage doesn't chase you, it runs away from you, and it is the goal.", ("mage", "fleeing", "goal")),
        ("the owl won't budge and carries the note.", ("bird", "immovable", "message")),
        # a negation ends with its clause: only "move" is negated here, not the goal
        ("the bird that doesn't move is the crucial goal.", ("bird", "immovable", "goal")),
        # the stress set's movement phrasings and typos
        ("the jet backs off, it's the enemy", ("airplane", "fleeing", "enemy")),
        ("ok so the birdie heads your way and it's the goal", ("bird", "chaser", "goal")),
        ("the wiazrd doesnt' move and is the enmey", ("mage", "immovable", "enemy")),
    ],
)
def test_negations_and_free_form(text, expected):
    assert parse_description(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        # an idiom holding another value's cue is read whole: "stays" alone would be immovable
        ("the hound stays away from you and is the goal", ("dog", "fleeing", "goal")),
        ("the hound stays on your tail and is the goal", ("dog", "chaser", "goal")),
        # idioms that only occur negated: the negation does not cancel them
        ("the hound won't leave you alone and is the goal", ("dog", "chaser", "goal")),
        ("the hound never leaves its spot and is the goal", ("dog", "immovable", "goal")),
        ("the hound never lets you get close and is the goal", ("dog", "fleeing", "goal")),
        # "news" is a message cue, "bad news" an enemy; where the message is is not where it goes
        ("the hound is bad news and zeroes in on you", ("dog", "chaser", "enemy")),
        ("the hound is where the message is; it never stirs", ("dog", "immovable", "message")),
        ("the hound is where you bring the message; it makes a run for it", ("dog", "fleeing", "goal")),
    ],
)
def test_idioms(text, expected):
    assert parse_description(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        # a negation's scope ends at a modal or a new predicate's verb
        ("a salmon that never moves receives the message.", ("fish", "immovable", "goal")),
        ("a crook that does not move will kill you on contact.", ("thief", "immovable", "enemy")),
        ("the plane must never be touched and stays put.", ("airplane", "immovable", "enemy")),
        # "non-moving" holds the chaser's cue "moving"
        ("the non-moving thief is the most dangerous opponent.", ("thief", "immovable", "enemy")),
        ("the enemy is the dog and it is moving farther away.", ("dog", "fleeing", "enemy")),
        # "still" as an adverb and "remains" as a linking verb say nothing of movement
        ("though the shark is fleeing, it is still a deadly opponent.", ("fish", "fleeing", "enemy")),
        ("the queen escapes from you and remains the goal.", ("queen", "fleeing", "goal")),
        ("the queen stays still and is the goal.", ("queen", "immovable", "goal")),
        # being relocated is not moving by itself; relocating is moving
        ("the ferry cannot be relocated and holds the message.", ("ship", "immovable", "message")),
        ("the relocating hound is the goal.", ("dog", None, "goal")),
    ],
)
def test_the_training_files_misreadings(text, expected):
    assert parse_description(text) == expected


def test_common_words_are_not_mended_into_keywords():
    # one letter from a keyword is a typo only for a word that is no word of its own
    assert normalise("a friend looks around among us, carried along") == "a friend looks around among us, carried along"
    assert normalise("the plane zetoes in on you") == "the plane zeroes in on you"


def test_a_lone_negation_is_no_answer():
    # "not the goal" alone leaves enemy and message: the parser must not answer "goal"
    assert parse_role("the hound is not the goal") is None
    assert parse_movement("the hound is not chasing you") is None
    assert parse_role("the harmless hound is the message") == "message"


def test_the_encoder_guess_never_answers_what_a_negation_denies():
    from lwm_models.world.frozen_text import FrozenTextEncoder

    encoder = FrozenTextEncoder()
    assert parse_role("the hound is not the goal", encoder) != "goal"
    assert parse_role("the hound is not the goal and not the enemy", encoder) == "message"
    # no keyword says how it moves; the guess reads the clause
    assert parse_movement("the hound is bolted to its square") is None
    assert parse_movement("the hound is bolted to its square", encoder) == "immovable"


def test_a_misspelt_short_name_is_read_where_no_keyword_is():
    from lwm_models.text.parser import _misspelt_identity, parse_identity
    from lwm_models.world.frozen_text import FrozenTextEncoder

    encoder = FrozenTextEncoder()
    # Too short for the keywords' typo correction, and no word the encoder knows whole.
    for text, name in [
        ("watch out, the dgo chases you and its deadly", "dog"),
        ("the quen has the message and keeps running away", "queen"),
        ("the fissh is immobile and has the message", "fish"),
        ("the thef is the goal", "thief"),
    ]:
        assert parse_identity(text) is None, text
        assert parse_identity(text, encoder) == name, text
    # Real words one letter from a name ("make": mage, "call": ball, "shop": ship) are not typos.
    assert _misspelt_identity("make the call at the shop", encoder) is None
    # One typo from an identity's own name and from another's synonym (robot, robin): the name's.
    assert _misspelt_identity("the robit stays put", encoder) == "robot"
    # Two misspelt names: no answer from this stage.
    assert _misspelt_identity("the dgo and the quen", encoder) is None


def test_stress_set_negation_style():
    # The negation style fails without negation handling (tuning part 44% role, held-out 36%
    # before it was written), and the held-out part was never tuned on.
    tune = parser_accuracy(stress_texts("tune", "negation"))
    heldout = parser_accuracy(stress_texts("heldout", "negation"))
    assert tune["role"] >= 0.95 and tune["movement"] >= 0.95, tune
    assert heldout["role"] >= 0.65, heldout


def test_routing():
    assert route_identity_id("the hound is deadly") == IDENTITIES["dog"]
    assert route_identity_id("something unspeakable") == 0


@pytest.mark.skipif(not VAL.is_file(), reason="shared human-written descriptions not available")
def test_accuracy_on_held_out_human_descriptions():
    # The keyword lists were written looking only at text_train.json's misparses.
    acc = parser_accuracy(load_description_file(VAL))
    assert acc["identity"] >= 0.95 and acc["movement"] >= 0.85 and acc["role"] >= 0.9, acc
