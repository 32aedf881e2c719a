"""Free-form Messenger descriptions written from hand-made phrase banks (issue 30).

Three banks that share no template and as few phrases as possible:

- "tune": what the keyword parser may be tuned on and a world model may be trained on;
- "dev": what chooses between ways of reading (e.g. the hedged reading's rule); nothing is
  trained on it and the parser is not tuned on it, so it shows how a choice fares on wording
  the parser never saw;
- "heldout": what measures reading; nothing is ever tuned or trained on it.

`scripts/make_stress_set.py` writes the stress set (`stress_set.json`) from both banks.
`training_texts` writes many more "tune" descriptions for training triples: the free-form part of
a robust world model's training mix (`lwm train --manual-mix`). Every phrase was written for this
project.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..messenger.constants import Triple
from .generator import generate_descriptions

STYLES = ("casual", "long-winded", "negation", "typos", "rare-synonyms", "reordered", "multi-fact")

# Plain names people use for the sprites; both parts use them outside the rare-synonyms style,
# since a person writing casually says "dog", whatever the part.
PLAIN = {
    "airplane": ["plane", "airplane", "jet"],
    "mage": ["wizard", "mage", "sorcerer"],
    "dog": ["dog", "hound", "puppy"],
    "bird": ["bird", "birdie", "little bird"],
    "fish": ["fish", "fishy", "big fish"],
    "scientist": ["scientist", "researcher", "science guy"],
    "thief": ["thief", "robber", "crook"],
    "ship": ["ship", "boat", "sailing ship"],
    "ball": ["ball", "round ball", "bouncy ball"],
    "robot": ["robot", "bot", "robot guy"],
    "queen": ["queen", "royal lady", "queen lady"],
    "sword": ["sword", "blade", "steel sword"],
}

BANKS = {
    "tune": {
        "rare_identity": {
            "airplane": ["turboprop", "aeroplane", "monoplane"],
            "mage": ["thaumaturge", "warlock", "hexer"],
            "dog": ["whelp", "mutt", "mongrel"],
            "bird": ["wren", "finch", "songbird"],
            "fish": ["mackerel", "guppy", "pike"],
            "scientist": ["boffin", "chemist", "lab technician"],
            "thief": ["cutpurse", "burglar", "footpad"],
            "ship": ["freighter", "schooner", "dinghy"],
            "ball": ["spheroid", "orb", "sphere"],
            "robot": ["automaton", "droid", "mechanoid"],
            "queen": ["czarina", "monarch", "her majesty"],
            "sword": ["cutlass", "claymore", "falchion"],
        },
        # noun phrases that fit after "is"
        "role": {
            "enemy": ["the enemy", "a killer", "your foe", "lethal to touch", "out to get you"],
            "message": ["the message", "the one with the note", "carrying the secret papers", "holding the letter"],
            "goal": ["the goal", "where the message must go", "the destination", "who you hand the message to"],
        },
        "rare_role": {
            "enemy": ["a nemesis", "baneful", "a mortal peril"],
            "message": ["the missive bearer", "the keeper of the epistle", "toting the missive"],
            "goal": ["the terminus", "the consignee", "the endpoint of your errand"],
        },
        # negated roles: what the entity is NOT
        "not_role": {
            "enemy": ["the enemy", "an enemy", "dangerous"],
            "message": ["the message", "carrying the message", "the note holder"],
            "goal": ["the goal", "the destination", "the target"],
        },
        # third-person verb phrases
        "move": {
            "chaser": ["chases you", "heads your way", "comes after you", "keeps following you", "homes in on you"],
            "fleeing": ["backs off", "runs away from you", "keeps its distance", "scurries off", "shies away from you"],
            "immovable": ["stays put", "never moves", "doesn't move", "sits still", "is rooted to the spot"],
        },
        "rare_move": {
            "chaser": ["tails you", "shadows you everywhere", "pursues you doggedly"],
            "fleeing": ["skedaddles", "absconds from you", "scarpers"],
            "immovable": ["is sedentary", "is anchored in place", "is immobile"],
        },
        "not_move": {
            "chaser": ["doesn't chase you", "does not come at you"],
            "fleeing": ["doesn't run away", "does not flee"],
            "immovable": ["isn't stationary", "does not stay still"],
        },
        "adj_move": {"chaser": "pursuing", "fleeing": "skittish", "immovable": "motionless"},
        "templates": {
            "casual": [
                "ok so the {I} {M} and it's {R}",
                "lol the {I}? {R}. it {M}",
                "heads up, {I} {M}, it's {R}",
            ],
            "long-winded": [
                "If you take a careful look around the board you will notice the {I}, which, as far as anyone "
                "can tell, {M}; and you should keep in mind that it is {R}, which matters a great deal here.",
                "There is, among the various things you might run into, a {I}, and what you ought to know about "
                "it is that it {M} and that, in the grand scheme of this little game, it is {R}.",
            ],
            "negation": [
                "the {I} is not {NR}; it {M} and it is {R}.",
                "not {NR}: the {I} {M}, it's {R}",
                "the {I} isn't {NR} and isn't {NR2}. it {M}.",
                "the {I} {NM}, it {M}, and it's {R}",
            ],
            "typos": [
                "the {I} {M} and is {R}",
                "that {I} is {R}, it {M}",
            ],
            "rare-synonyms": [
                "the {I} {M} and is {R}.",
                "beware, the {I} is {R} and {M}.",
            ],
            "reordered": [
                "{R}, that's the {I}, and it {M}.",
                "it {M}, this {I}, and it is {R}.",
            ],
            "multi-fact": [
                "the {A} {I} is {R}, it {M}, and it looks harmless at first glance.",
                "the {I} {M}, and since it is {R} you should plan your route around it.",
            ],
        },
        "typo_kind": "swap",
    },
    "heldout": {
        "rare_identity": {
            "airplane": ["biplane", "jetliner", "aircraft"],
            "mage": ["archmage", "enchanter", "magus"],
            "dog": ["canine", "pup", "bloodhound"],
            "bird": ["starling", "kestrel", "feathered critter"],
            "fish": ["herring", "sardine", "finned swimmer"],
            "scientist": ["physicist", "egghead", "experimenter"],
            "thief": ["pickpocket", "safecracker", "cat burglar"],
            "ship": ["galleon", "steamship", "trawler"],
            "ball": ["globe", "beach ball", "round plaything"],
            "robot": ["android", "tin man", "machine man"],
            "queen": ["empress", "sovereign", "lady of the throne"],
            "sword": ["rapier", "longsword", "broadsword"],
        },
        "role": {
            "enemy": ["the bad guy", "hostile", "an adversary", "going to end you", "deadly"],
            "message": ["the courier's package", "bearing the dispatch", "the holder of the intel", "keeping the memo"],
            "goal": ["the drop-off point", "the receiver", "the final stop for the message", "the objective"],
        },
        "rare_role": {
            "enemy": ["malevolent", "an antagonist", "a menace to your life"],
            "message": ["the dispatch", "the bearer of tidings", "entrusted with the communique"],
            "goal": ["the rendezvous point", "the addressee", "the place your errand ends"],
        },
        "not_role": {
            "enemy": ["hostile", "a threat", "your enemy"],
            "message": ["carrying anything", "the one with the letter", "holding the message"],
            "goal": ["the place to deliver to", "the goal", "your objective"],
        },
        "move": {
            "chaser": [
                "makes a beeline for you",
                "closes in on you",
                "is on your tail",
                "hunts you down",
                "creeps toward you",
            ],
            "fleeing": [
                "bolts when you come near",
                "retreats from you",
                "scampers away",
                "avoids you",
                "keeps clear of you",
            ],
            "immovable": [
                "won't budge",
                "stands its ground",
                "holds its position",
                "doesn't go anywhere",
                "is stationary",
            ],
        },
        "rare_move": {
            "chaser": ["gives chase", "bears down on you", "dogs your footsteps"],
            "fleeing": ["decamps", "beats a retreat", "takes flight from you"],
            "immovable": ["is stock-still", "is inert", "is fixed to the floor"],
        },
        "not_move": {
            "chaser": ["never comes after you", "will not pursue you"],
            "fleeing": ["won't run from you", "never retreats"],
            "immovable": ["is not stuck in one spot", "never stays still"],
        },
        "adj_move": {"chaser": "hunting", "fleeing": "timid", "immovable": "frozen"},
        "templates": {
            "casual": [
                "yeah the {I} is {R}, and it {M}",
                "fyi the {I} {M}... {R} btw",
                "so basically {I} = {R}, it {M}",
            ],
            "long-winded": [
                "Now, I want to be thorough, so let me tell you about the {I}: over the course of the game it "
                "{M}, and beyond that, it's worth remembering at every moment that it is {R}.",
                "You may or may not have seen one before, but in this particular game the {I} is {R}, and, "
                "for whatever reason the designers had in mind, it {M} from the first turn to the last.",
            ],
            "negation": [
                "the {I} is by no means {NR}. it {M}; it is {R}.",
                "the {I} is neither {NR} nor {NR2}, and it {M}.",
                "don't take the {I} for {NR}, it is {R} and it {M}",
                "the {I} {NM}; rather, it {M} and it is {R}.",
            ],
            "typos": [
                "watch the {I}, it is {R} and it {M}",
                "{I} here: {R}, {M}",
            ],
            "rare-synonyms": [
                "know that the {I} {M}; it is {R}.",
                "the {I}, {R}, {M}.",
            ],
            "reordered": [
                "{R}: that describes the {I}, which {M}.",
                "always it {M}, the {I}, being {R}.",
            ],
            "multi-fact": [
                "the {I} is {R} and it {M}, and honestly the {A} {I} is the one you'll remember.",
                "keep an eye on the {A} {I}: it {M}, it is {R}, and it never changes its mind.",
            ],
        },
        "typo_kind": "drop-double",
    },
    "dev": {
        "rare_identity": {
            "airplane": ["seaplane", "airliner", "flying machine"],
            "mage": ["necromancer", "spellcaster", "conjurer"],
            "dog": ["cur", "terrier", "four-legged barker"],
            "bird": ["sparrow", "robin", "winged thing"],
            "fish": ["trout", "carp", "scaly swimmer"],
            "scientist": ["lab coat", "researcher in goggles", "professor"],
            "thief": ["bandit", "swindler", "light-fingered rogue"],
            "ship": ["frigate", "clipper", "vessel"],
            "ball": ["sphere toy", "rubber ball", "bouncer"],
            "robot": ["cyborg", "metal man", "mech"],
            "queen": ["matriarch", "ruler", "crowned lady"],
            "sword": ["scimitar", "saber", "blade of steel"],
        },
        "role": {
            "enemy": ["the danger", "a murderer", "the one that kills you", "bad news", "trouble"],
            "message": ["the package", "the thing you must pick up", "where the message is", "the letter carrier"],
            "goal": ["the target", "the delivery point", "where you bring the message", "the recipient"],
        },
        "rare_role": {
            "enemy": ["pernicious", "a bloodthirsty assailant", "an executioner"],
            "message": ["the parcel bearer", "the custodian of the note", "the holder of the scroll"],
            "goal": ["the intended recipient", "the journey's end", "the drop site"],
        },
        "not_role": {
            "enemy": ["harmful", "the killer", "out to hurt you"],
            "message": ["the package", "where the letter is", "the carrier"],
            "goal": ["the recipient", "where the letter goes", "the delivery point"],
        },
        "move": {
            "chaser": [
                "is gunning for you",
                "zeroes in on you",
                "won't leave you alone",
                "is hot on your heels",
                "makes straight for you",
            ],
            "fleeing": [
                "hightails it when you show up",
                "is always on the run from you",
                "gives you a wide berth",
                "makes a run for it",
                "darts off when you get close",
            ],
            "immovable": [
                "never leaves its spot",
                "is glued in place",
                "stays planted",
                "just sits there",
                "is still as a statue",
            ],
        },
        "rare_move": {
            "chaser": ["stalks you", "trails you", "is in hot pursuit"],
            "fleeing": ["withdraws", "evades you", "makes itself scarce"],
            "immovable": ["is static", "is fixed in place", "is parked for good"],
        },
        "not_move": {
            "chaser": ["isn't chasing you", "doesn't follow you"],
            "fleeing": ["isn't running away", "doesn't escape"],
            "immovable": ["isn't still", "doesn't stay put"],
        },
        "adj_move": {"chaser": "relentless", "fleeing": "shy", "immovable": "idle"},
        "templates": {
            "casual": [
                "the {I}: {R}. {M} too",
                "btw the {I} {M}, pretty sure it's {R}",
                "{I}? it's {R} and {M} lol",
            ],
            "long-winded": [
                "Before you set off, there is one more piece of the puzzle to consider, namely the {I}; from what "
                "we have seen it {M}, and, importantly for how you play, it is {R} in this round.",
                "I should mention, for the sake of completeness and so you are not caught off guard, that the {I} "
                "is {R}, and also that, throughout the whole episode, it {M}.",
            ],
            "negation": [
                "the {I}, which {M}, is {R} and not {NR}.",
                "no, the {I} is not {NR}; it's {R}, and it {M}",
                "the {I} isn't {NR2}. it {M} and it's {R}",
                "careful: the {I} {NM}. it {M}, and it is {R}.",
            ],
            "typos": [
                "teh {I} is {R} and {M}",
                "the {I} {M}. its {R}",
            ],
            "rare-synonyms": [
                "the {I} is {R}; it {M}.",
                "mark the {I}: it {M} and is {R}.",
            ],
            "reordered": [
                "{M}, that {I} does, and {R} it is.",
                "being {R}, the {I} {M}.",
            ],
            "multi-fact": [
                "the {A} {I} {M}; it is {R}, and it is larger than the others.",
                "the {I} is {R}, it {M}, and the {A} {I} is easy to spot on the board.",
            ],
        },
        "typo_kind": "neighbour",
    },
}


# A key's neighbour on a QWERTY keyboard, one each: the development part's typos.
NEIGHBOUR = dict(zip("abcdefghijklmnopqrstuvwxyz", "snvfrghjoklknmpowtdyibecux"))


def typo(text: str, kind: str, rng: np.random.Generator) -> str:
    """Misspell about every third word of four letters or more: adjacent letters swapped ("swap")
    in the tuning part, a letter dropped or doubled ("drop-double") in the held-out part, a letter
    struck by its neighbouring key ("neighbour") in the development part."""
    words = text.split(" ")
    for k, w in enumerate(words):
        core = w.strip(".,;:!?'")
        if len(core) < 4 or rng.random() > 0.35:
            continue
        i = int(rng.integers(1, len(core) - 1))
        if kind == "swap":
            new = core[:i] + core[i + 1] + core[i] + core[i + 2 :]
        elif kind == "neighbour":  # a letter struck by the key beside it
            new = core[:i] + NEIGHBOUR.get(core[i], core[i]) + core[i + 1 :]
        elif rng.random() < 0.5:
            new = core[:i] + core[i + 1 :]
        else:
            new = core[:i] + core[i] + core[i:]
        words[k] = w.replace(core, new, 1)
    return " ".join(words)


def describe(part: str, style: str, triple: tuple[str, str, str], rng: np.random.Generator) -> str:
    ident, movement, role = triple
    bank = BANKS[part]
    pick = lambda options: options[int(rng.integers(len(options)))]  # noqa: E731
    rare = style == "rare-synonyms"
    names = bank["rare_identity"][ident] if rare else PLAIN[ident]
    other_roles = [r for r in ("enemy", "message", "goal") if r != role]
    rng.shuffle(other_roles)
    other_moves = [m for m in ("chaser", "fleeing", "immovable") if m != movement]
    template = pick(bank["templates"][style])
    text = template.format(
        I=pick(names),
        R=pick(bank["rare_role" if rare else "role"][role]),
        M=pick(bank["rare_move" if rare else "move"][movement]),
        NR=pick(bank["not_role"][other_roles[0]]),
        NR2=pick(bank["not_role"][other_roles[1]]),
        NM=pick(bank["not_move"][pick(other_moves)]),
        A=bank["adj_move"][movement],
    )
    if style == "typos":
        text = typo(text, bank["typo_kind"], rng)
    return text


MIX_SOURCES = ("both", "generated", "free-form")


def training_texts(
    triples: Iterable[Triple], per_style: int = 12, seed: int = 0, source: str = "both"
) -> dict[Triple, list[str]]:
    """Descriptions of `triples` for a training mix: the generator's, and up to `per_style`
    distinct "tune"-bank descriptions in each style (`source`: both, or one of the two). Never the
    held-out bank."""
    if source not in MIX_SOURCES:
        raise ValueError(f"unknown mix source {source!r}; known: {', '.join(MIX_SOURCES)}")
    rng = np.random.default_rng([seed, 0x545255])
    out: dict[Triple, list[str]] = {}
    for triple in triples:
        texts = dict.fromkeys(generate_descriptions(triple) if source != "free-form" else ())
        for style in STYLES if source != "generated" else ():
            made: set[str] = set()
            for _attempt in range(4 * per_style):
                if len(made) >= per_style:
                    break
                made.add(describe("tune", style, tuple(triple), rng))
            texts.update(dict.fromkeys(sorted(made)))
        out[tuple(triple)] = list(texts)
    return out
