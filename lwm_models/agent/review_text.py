"""What a terminal shows of a review: a plan in a screenful, and one state of a label request.

The page draws every frame; a terminal cannot show 33 boards a plan and stay readable, so a plan
here is its story in one account (the shown trajectory, then its sampled futures), a legend of the
board's symbols and the actions' numbers, the start and the last board, and one line per step with
what happened there (a pick-up, a death, a win). `frames="all"` prints every board.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..messenger.constants import ACTION_DELTAS, ACTION_NAMES, AVATAR_CHANNEL, GRID, ID_TO_IDENTITY
from ..messenger.engine import grid_to_compact
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


WORSE_WHAT = {"corrections": "your correction", "imitation": "your teaching", "demonstrations": "your demonstrations",
              "manual": "your manual"}  # fmt: skip
WORSE_TAKE_BACK = {"terminal": "u takes it back", "page": "undo takes it back"}


def worse_text(plan: dict, where: str = "terminal") -> str:
    """A plan that looks worse than the one before the person's change, in words, with how to take
    the change back; '' for any other plan."""
    w = plan.get("worse")
    if not w:
        return ""
    f = plan["futures"]
    return (
        f"this plan looks worse than plan {w['plan']}, before {WORSE_WHAT[w['after']]}: its futures die "
        f"{f['death_share']:.0%} (were {w['death_share']:.0%}), mean return {f['return_mean']:+.2f} (was "
        f"{w['return_mean']:+.2f}); {WORSE_TAKE_BACK[where]}"
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
    if plan.get("worse"):
        lines.append(worse_text(plan))
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
    parts = [head, beside(("a step before", before), ("now", obs)) if before is not None else render_ascii(obs)]
    parts.append(f"{ACTIONS_KEY}; answer l {k}:ACTION (or several: l 0:3 1:4), s N to see state N")
    return "\n".join(parts)


def beside(*boards: tuple[str, Sequence]) -> str:
    """Boards side by side, each under its title (a person compares them line by line)."""
    drawn = [render_ascii(np.asarray(obs, dtype=np.uint8)).splitlines() for _, obs in boards]
    width = len(drawn[0][0]) + 3
    lines = ["".join(title.ljust(width) for title, _ in boards).rstrip()]
    lines += ["   ".join(rows) for rows in zip(*drawn, strict=True)]
    return "\n".join(lines)


def _compact(obs: Sequence) -> np.ndarray:
    a = np.asarray(obs, dtype=np.uint8)
    return grid_to_compact(a) if a.shape[-2:] != (AVATAR_CHANNEL + 1, 3) else a


def touched(before: Sequence, action: int, after: Sequence) -> list[str]:
    """The identities the avatar ran into on its last move. A sprite the avatar touches leaves the
    board if it is the message, or the goal on a win; one that stays (an enemy) is found at the
    avatar's cell after `action` from `before` (at a death the avatar itself leaves the board). A
    sprite overlaps the avatar within a cell on both axes, and entities move on half cells, so one
    shown a cell above or left of the avatar touches it too."""
    b, a = _compact(before), _compact(after)
    dr, dc = ACTION_DELTAS[action]
    row = min(max(int(b[AVATAR_CHANNEL, 1]) + dr, 0), GRID - 1)
    col = min(max(int(b[AVATAR_CHANNEL, 2]) + dc, 0), GRID - 1)
    stayed = {int(i) for i in a[:AVATAR_CHANNEL, 0] if i}
    near = [(0, int(i)) for i in b[:AVATAR_CHANNEL, 0] if i and int(i) not in stayed]
    near += [
        (1 + abs(int(r) - row) + abs(int(c) - col), int(i))
        for i, r, c in a[:AVATAR_CHANNEL]
        if i and row - 1 <= r <= row and col - 1 <= c <= col
    ]
    return [ID_TO_IDENTITY.get(i, f"sprite {i}") for _, i in sorted(near)]


def ending(report: dict) -> str:
    """How the real episode ended, in words, with what the avatar touched when it died or won."""
    steps, said = report["steps"], report["outcome"]
    obs, actions = report.get("observations") or [], report.get("actions") or []
    what = {"died": "the agent died", "won": "the agent won", "time_limit": "the agent ran out of time",
            "stopped": "you stopped the agent", "aborted": "you aborted the review"}.get(said, said)  # fmt: skip
    where = f" at step {steps}" if said in ("died", "won", "stopped") else f" after {steps} steps"
    cause = ""
    if said in ("died", "won") and len(obs) >= 2 and actions:
        names = touched(obs[-2], actions[-1], obs[-1])
        if names:
            cause = f", touching the {' and the '.join(names)}"
    return what + where + cause


REPORT_NEXT = (
    "what next: n the next episode | restart this episode | f every step, real beside imagined | "
    "m a new manual for this game"
)


def report_text(report: dict, frames: str = "ends") -> str:
    """An execution's report for a terminal: how it ended and why, the real episode beside the plan
    that was approved (its start, the step where they part, its end; frames='all': every step),
    and what the person can do next."""
    real = report.get("observations") or []
    planned = report.get("planned_observations") or []
    div = report["divergence"]
    asked = report.get("reviews_asked", 0)
    lines = [
        f"=== report of review {report['review_id']}: plan {report['plan_id']} after {report.get('revisions', 0)} "
        f"revision(s) ===",
        f"{ending(report)}: real return {report['real_return']:+.2f}, imagined {report['imagined_return']:+.2f}"
        + (f"; the agent stopped to ask you again {asked} time(s)" if asked else ""),
    ]
    if frames == "none" or not real:
        if not real:
            lines.append("the agent made no move in the real game")
        return "\n".join([*lines, REPORT_NEXT])
    parted = div.get("first_step")
    went = "went as imagined at every step" if parted is None else f"parted from the plan at step {parted}"
    lines.append(f"the real game {went}")
    lines.append(f"board: {board_legend(np.asarray(real[0], dtype=np.uint8), every_avatar=True)}")
    actions = report.get("actions") or []
    last = len(real) - 1
    shown = range(last + 1) if frames == "all" else sorted({0, *([parted] if parted else []), last})
    for t in shown:
        did = f", real action {ACTION_NAMES[actions[t - 1]]}" if 0 < t <= len(actions) else ""
        head = "start" if t == 0 else f"step {t}{did}" + (f" ({ending(report)})" if t == last else "")
        if t == last and report["outcome"] == "died":
            head += "; the avatar is off the board"
        imagined = planned[min(t, len(planned) - 1)] if planned else real[t]
        lines += [head, beside(("real", real[t]), (f"imagined (plan {report['plan_id']})", imagined))]
    if actions:
        lines.append("real steps: " + ", ".join(f"{t} {ACTION_NAMES[a]}" for t, a in enumerate(actions, 1)))
    lines.append(REPORT_NEXT)
    return "\n".join(lines)


__all__ = ["beside", "ending", "outcome", "plan_text", "question_text", "report_text", "state_text", "step_event",
           "touched", "worse_text"]  # fmt: skip
