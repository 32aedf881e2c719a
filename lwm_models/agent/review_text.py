"""What a terminal shows of a review: a plan in a screenful, and one state of a label request.

The page draws every frame; a terminal cannot show 33 boards a plan and stay readable, so a plan
here is its story in one account (the shown trajectory, then its sampled futures), a legend of the
board's symbols and the actions' numbers, the start and the last board, and one line per step with
what happened there (a pick-up, a death, a win). `frames="all"` prints every board.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..messenger.constants import ACTION_NAMES
from ..messenger.render import legend as board_legend
from ..messenger.render import render_ascii
from .understood import believed, describe, read_roles

ACTIONS_KEY = "actions: " + "  ".join(f"{i} {name}" for i, name in enumerate(ACTION_NAMES))


def step_event(reward: float, done: bool) -> str:
    """What a step's imagined reward says happened."""
    if reward <= -1.0:
        return "dies"
    if reward >= 1.0:
        return "wins" if done else "+1"
    if reward > 0:
        return "picks up the message"
    return "ends" if done else ""


def outcome(plan: dict) -> str:
    """The shown trajectory's end, in words: where it dies or wins, or how long it runs."""
    for t, (reward, done) in enumerate(zip(plan["rewards"], plan["dones"], strict=True), 1):
        if reward <= -1.0:
            return f"dies at step {t}"
        if done and reward >= 1.0:
            return f"wins at step {t}"
    return f"runs {len(plan['actions'])} steps without an end"


def progress_text(progress: dict) -> str:
    """The agent teaching itself from a manual, in a line: what it does and how far it is."""
    manual = f"manual v{progress['manual_version']}" if "manual_version" in progress else "the manual"
    if not progress["done"]:
        read = f"the world model read {manual} as: {read_roles(progress['roles'])}; " if progress.get("roles") else ""
        return (
            f"{read}the agent is learning from {manual} in imagination: round {progress['round']} of "
            f"{progress['rounds']} ({progress['seconds']:.0f} s); its plan follows"
        )
    roles = f"; {believed(progress['roles'])}" if progress.get("roles") else ""
    return f"the agent learnt from {manual} in {progress['seconds']:.0f} s ({progress['round']} rounds){roles}"


REPEATS = (
    "the same moves as plan {plan}, which you rejected: rejecting alone changes nothing the agent has learnt. "
    "To change the plan, correct a step (c STEP:ACTION), teach it (i) or rewrite the manual (m)"
)


def plan_text(plan: dict, frames: str = "ends") -> str:
    """A plan for a terminal. frames: 'ends' (the start and the last board), 'all' or 'none'."""
    f = plan["futures"]
    start = plan.get("start_step", 0)
    lines = [
        f"=== plan {plan['plan_id']} of review {plan['review_id']} ({plan.get('reason', '')}), manual "
        f"v{plan['manual_version']}" + (f", from real step {start}" if start else "") + " ===",
        f"the plan: return {plan['imagined_return']:+.2f}, {outcome(plan)}; "
        f"its {f['k']} sampled futures: {f['death_share']:.0%} die, {f['win_share']:.0%} win, "
        f"mean return {f['return_mean']:+.2f}",
    ]
    if plan.get("repeats"):
        lines.append(REPEATS.format(plan=plan["repeats"]))
    if plan.get("questions"):
        lines.append(question_text(plan))
    if frames == "none":
        return "\n".join(lines)
    first = np.asarray(plan["observations"][0], dtype=np.uint8)
    # Both avatar symbols are named: the start shows '@', a later board '&' once the message is carried.
    lines += [f"board: {board_legend(first, every_avatar=True)}", ACTIONS_KEY]
    for entry in plan.get("understood", []):  # what the world model made of the manual
        lines.append(f"imagined {entry['identity']}: {describe(entry)}")
    if plan.get("roles"):
        lines.append(believed(plan["roles"]))
    steps = []
    for t, action in enumerate(plan["actions"], 1):
        said = step_event(plan["rewards"][t - 1], plan["dones"][t - 1])
        steps.append(f"{t} {ACTION_NAMES[action]}" + (f" ({said})" if said else ""))
    shown = range(len(plan["observations"])) if frames == "all" else sorted({0, len(plan["observations"]) - 1})
    for t in shown:
        lines.append("start" if t == 0 else f"after step {t}: {steps[t - 1]}")
        lines.append(render_ascii(np.asarray(plan["observations"][t], dtype=np.uint8)))
    lines.append("steps: " + ", ".join(steps))
    return "\n".join(lines)


def question_text(plan: dict) -> str:
    """The plan's first question about the manual, with its answers numbered for `q N`."""
    q = plan["questions"][0]
    offered = ", ".join(f"q {k} {c['words']}" for k, c in enumerate(q["choices"], 1))
    more = len(plan["questions"]) - 1
    return (f"the agent is not sure ({q['p']:.0%}): {q['text']} answer {offered}"
            + (f" ({more} more question(s) after this)" if more else ""))  # fmt: skip


def state_text(request: dict, k: int, before: Sequence | None = None) -> str:
    """State k of a label request, with the board a step earlier in its imagined episode (a person
    judges movement from two boards)."""
    obs = np.asarray(request["observations"][k], dtype=np.uint8)
    head = (
        f"state {k} of {len(request['observations'])} (imagined episode {request['trajectories'][k]}, "
        f"step {request['steps'][k]}); board: {board_legend(obs, every_avatar=True)}"
    )
    parts = [head]
    if before is not None:
        left = render_ascii(np.asarray(before, dtype=np.uint8)).splitlines()
        right = render_ascii(obs).splitlines()
        parts.append("a step before".ljust(len(left[0]) + 3) + "now")
        parts += [f"{a}   {b}" for a, b in zip(left, right, strict=True)]
    else:
        parts.append(render_ascii(obs))
    parts.append(f"{ACTIONS_KEY}; answer l {k}:ACTION (or several: l 0:3 1:4), s N to see state N")
    return "\n".join(parts)


__all__ = ["outcome", "plan_text", "question_text", "state_text", "step_event"]
