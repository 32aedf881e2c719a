"""What a review page shows of the review's messages: each imagined or real frame as the cells to
draw (the board rules of messenger/render.py, so the page and the PNGs agree), and the manual as
a legend of identity, movement and role: as the agent reads the manual before acting (a plan's
`roles`, the manual's reading), else as the project's parser reads each description. The page
only draws; a description the parser cannot read shows as unknown, as it is to the reader too.
Label requests come with their states' frames and where each state's trajectory was a step
before; the ledger's records with a line of text each (as `lwm ledger show` prints them).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..ledger import headline
from ..messenger.render import board, identity_style, symbol_key
from ..text.parser import parse_description
from .review_text import progress_text, worse_text
from .understood import believed, describe


def frames(observations: Sequence) -> list[list[dict]]:
    return [board(np.asarray(obs, dtype=np.uint8)) for obs in observations]


def legend(descriptions: Sequence[str], roles: Sequence[dict] | None = None) -> list[dict]:
    """Per entity, what the agent reads of it: with `roles` (a plan's, the manual's reading) its
    role and movement as the agent acts on them, so the page shows one reading; else per
    description as the parser reads it."""
    if roles:
        out = []
        for e in roles:
            letter, colour = identity_style(e["identity"])
            moves = e.get("movement")
            if moves and "movement_p" in e:
                moves = f"{moves} ({e['movement_p']:.0%} sure)"
            out.append({"description": "", "identity": e["identity"], "movement": moves,
                        "role": f"{e['role']} ({e['p']:.0%} sure)", "letter": letter, "colour": colour})  # fmt: skip
        return out
    out = []
    for text in descriptions:
        identity, movement, role = parse_description(text)
        letter, colour = identity_style(identity) if identity else ("?", "#808080")
        out.append(
            {
                "description": text,
                "identity": identity,
                "movement": movement,
                "role": role,
                "letter": letter,
                "colour": colour,
            }
        )
    return out


# What the page says of a plan that makes a rejected plan's moves again (`review_text.REPEATS`).
REPEATS_ON_PAGE = (
    "The same moves as plan {plan}, which you rejected: rejecting alone changes nothing the agent has learnt. "
    "To change the plan, correct a step, teach it or rewrite the manual."
)


def plan_view(plan: dict) -> dict:
    """A plan message with its frames, its manual's legend (as the parser reads the text) and what
    the world model imagined of each entity (as the plan and its futures show it)."""
    imagined = []
    for entry in plan.get("understood", []):
        letter, colour = identity_style(entry["identity"])
        imagined.append({"identity": entry["identity"], "letter": letter, "colour": colour, "said": describe(entry)})
    believes = believed(plan["roles"]) if plan.get("roles") else None
    repeats = REPEATS_ON_PAGE.format(plan=plan["repeats"]) if plan.get("repeats") else ""
    return {**plan, "frames": frames(plan["observations"]), "legend": legend(plan["manual"], plan.get("roles")),
            "imagined": imagined, "believes": believes, "board_key": symbol_key(), "repeats_text": repeats,
            "worse_text": worse_text(plan, "page")}  # fmt: skip


def progress_view(progress: dict) -> dict:
    """A progress message with the line the terminal prints, so the page says the same."""
    return {**progress, "text": progress_text(progress)}


def report_view(report: dict) -> dict:
    """An execution report with the real and the planned frames side by side, and the key of the
    symbols that are no identity's letter (the avatar, carrying the message or not)."""
    return {
        **report,
        "real_frames": frames(report.get("observations", [])),
        "planned_frames": frames(report.get("planned_observations", [])),
        "board_key": symbol_key(),
    }


def label_request_view(request: dict) -> dict:
    """A label request with its states' frames, `before[k]`: the state of the same imagined
    trajectory one step earlier (-1 at its start: a person judges movement from two frames), and
    `order`, the order the page walks the states in. A request of chosen states (it carries the
    board before each, `previous`): by state number, as the terminal lists them and the labels
    name them, each state standing alone. A whole round: trajectory by trajectory, step by step,
    the order a person follows an episode in (the request lists them step by step across
    trajectories)."""
    steps, trajectories = request["steps"], request["trajectories"]
    at = {(traj, step): k for k, (traj, step) in enumerate(zip(trajectories, steps, strict=True))}
    previous = request.get("previous")  # a request of chosen states carries the board before each
    order = list(range(len(steps)))
    if previous is None:
        order.sort(key=lambda k: (trajectories[k], steps[k]))
    return {
        **request,
        "frames": frames(request["observations"]),
        "before": [at.get((traj, step - 1), -1) for traj, step in zip(trajectories, steps, strict=True)],
        "before_frames": None if previous is None else [None if o is None else frames([o])[0] for o in previous],
        "order": order,
    }


def history_view(records: Sequence[dict]) -> list[dict]:
    """A review's ledger records as the page lists them: kind, time, one line of text, and the
    frames of plans (imagined) and reports (real), which the page can step through; the rest of
    a payload (signatures, futures) stays in the ledger."""
    out = []
    for record in records:
        drawn = record["kind"] in ("plan", "report")
        out.append(
            {
                "id": record["id"],
                "kind": record["kind"],
                "time": record["time"],
                "text": headline(record),
                **({"frames": frames(record["payload"].get("observations") or [])} if drawn else {}),
            }
        )
    return out


__all__ = [
    "answered_manual",
    "frames",
    "history_view",
    "label_request_view",
    "legend",
    "plan_view",
    "progress_view",
    "report_view",
]


def answered_manual(plan: dict | None, words: list[str]) -> dict:
    """The manual payload that answers a plan's first question with choice `words[0]` (1, 2 or 3):
    the plan's manual, with the facts stated so far and this one. ValueError in plain words when
    there is nothing to answer or the choice is not one of the question's."""
    questions = (plan or {}).get("questions") or []
    if not questions:
        raise ValueError("the plan asks no question about the manual")
    q = questions[0]
    n = len(q["choices"])
    if len(words) != 1 or not words[0].isdigit() or not 1 <= int(words[0]) <= n:
        offered = ", ".join(f"{k} {c['words']}" for k, c in enumerate(q["choices"], 1))
        raise ValueError(f"answer with one choice number: q 1 to q {n} ({offered})")
    fact = {"entity": q["entity"], "field": q["field"], "value": q["choices"][int(words[0]) - 1]["value"]}
    return {"descriptions": list(plan["manual"]), "facts": [*plan.get("facts", []), fact], "source": "human"}
