"""What a review page shows of the review's messages: each imagined or real frame as the cells to
draw (the board rules of messenger/render.py, so the page and the PNGs agree), and the manual as
a legend of identity, movement and role as the project's parser reads each description. The page
only draws; a description the parser cannot read shows as unknown, as it is to the reader too.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..messenger.render import board, identity_style
from ..text.parser import parse_description


def frames(observations: Sequence) -> list[list[dict]]:
    return [board(np.asarray(obs, dtype=np.uint8)) for obs in observations]


def legend(descriptions: Sequence[str]) -> list[dict]:
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


def plan_view(plan: dict) -> dict:
    """A plan message with its frames and its manual's legend."""
    return {**plan, "frames": frames(plan["observations"]), "legend": legend(plan["manual"])}


def report_view(report: dict) -> dict:
    """An execution report with the real and the planned frames side by side."""
    return {
        **report,
        "real_frames": frames(report.get("observations", [])),
        "planned_frames": frames(report.get("planned_observations", [])),
    }


__all__ = ["frames", "legend", "plan_view", "report_view"]
