"""The terminal's view of a review: a plan in a screenful, one account of its outcome, and a
label request's state beside the state before it."""

from __future__ import annotations

import copy

from lwm_models import messages
from lwm_models.agent.review_text import outcome, plan_text, state_text
from lwm_models.agent.review_view import plan_view


def test_a_plan_tells_its_outcome_once_with_a_legend_and_its_ends():
    plan = messages.schema("plan")["examples"][0]
    text = plan_text(plan)
    assert "the plan: return +1.50, wins at step 10" in text and "2 sampled futures: 100% die" in text
    assert "board: A airplane  L ball  R robot  @ you" in text and "actions: 0 up  1 down  2 left" in text
    # The start shows '@'; the legend names '&' too, which the boards after the pick-up show.
    assert "@ you  & you, carrying the message\n" in text
    assert "7 down (picks up the message)" in text and "10 right (wins)" in text
    assert text.count("+---") == 4  # two boards: the start and the last
    assert plan_text(plan, "all").count("+---") == 2 * len(plan["observations"])
    assert len(plan_text(plan, "none").splitlines()) == 2


def test_a_plan_that_dies_says_where():
    plan = copy.deepcopy(messages.schema("plan")["examples"][0])
    plan["rewards"][3], plan["dones"][3] = -1.0, True
    assert outcome(plan) == "dies at step 4" and "4 down (dies)" in plan_text(plan)


def test_a_label_request_state_is_shown_beside_the_one_before_it():
    request = messages.schema("label_request")["examples"][0]
    alone = state_text(request, 0)
    assert "@ you  & you, carrying the message" in alone  # the board a step before may show the other
    assert alone.startswith("state 0 of 3") and alone.count("+---") == 2 and "l 0:ACTION" in alone
    paired = state_text(request, 1, request["observations"][0])
    assert "a step before" in paired and paired.count("+---") == 4 and "+   +---" in paired  # side by side


def test_the_roles_the_agent_acts_on_are_said_on_the_terminal_and_the_page():
    from lwm_models.agent.review_view import plan_view

    plan = copy.deepcopy(messages.schema("plan")["examples"][0])
    assert "acts on" not in plan_text(plan) and plan_view(plan)["believes"] is None  # no belief: nothing said
    plan["roles"] = [
        {"id": 2, "identity": "airplane", "role": "enemy", "p": 0.91},
        {"id": 7, "identity": "ball", "role": "message", "p": 0.55},
        {"id": 10, "identity": "robot", "role": "goal", "p": 0.91},
    ]
    said = "the agent acts on: airplane the enemy (91% sure), ball the message (unsure), robot the goal (91% sure)"
    assert said in plan_text(plan) and plan_view(plan)["believes"] == said
    for entry in plan["roles"]:  # a manual that says nothing usable: every role a guess
        entry["p"] = 0.34
    view = plan_view(plan)["believes"]
    assert view.endswith("a guess: the manual says nothing the agent can use about who is who"), view
    assert view in plan_text(plan)


def test_the_agent_learning_from_a_manual_is_said_in_a_line():
    from lwm_models.agent.review_text import progress_text

    progress = messages.schema("progress")["examples"][0]
    assert progress_text(progress) == (
        "the agent is learning from manual v2 in imagination: round 3 of 10 (6 s); its plan follows"
    )
    roles = [{"id": 2, "identity": "airplane", "role": "enemy", "p": 0.9}]
    done = {**progress, "round": 10, "seconds": 19.6, "done": True, "roles": roles}
    messages.validate("progress", done)
    assert progress_text(done) == (
        "the agent learnt from manual v2 in 20 s (10 rounds); the agent acts on: airplane the enemy (90% sure)"
    )
    # Round 0 carries what the world model read, before any learning: roles and movements.
    read = messages.schema("progress")["examples"][-1]
    messages.validate("progress", read)
    assert progress_text(read).startswith(
        "the world model read manual v2 as: airplane the enemy, comes toward you (93% sure), ball the message, "
        "moves away from you (93% sure), robot the goal, stays put (93% sure); the agent is learning"
    )


def test_a_question_about_the_manual_is_asked_and_answered_in_plain_words():
    import pytest

    from lwm_models.agent.review_view import answered_manual

    plan = copy.deepcopy(messages.schema("plan")["examples"][0])
    with pytest.raises(ValueError, match="asks no question"):
        answered_manual(plan, ["1"])
    plan["questions"] = [
        {"entity": "robot", "field": "movement", "p": 0.69,
         "text": "Does the robot stay where it is, move away from you or come toward you?",
         "choices": [{"value": "immovable", "words": "stays where it is"},
                     {"value": "fleeing", "words": "moves away from you"},
                     {"value": "chaser", "words": "comes toward you"}]},
    ]  # fmt: skip
    messages.validate("plan", plan)
    assert "the agent is not sure (69%): Does the robot stay where it is" in plan_text(plan)
    assert "q 1 stays where it is, q 2 moves away from you, q 3 comes toward you" in plan_text(plan, "none")
    for bad in ([], ["4"], ["x"], ["1", "2"]):
        with pytest.raises(ValueError, match="answer with one choice number: q 1 to q 3"):
            answered_manual(plan, bad)
    answer = answered_manual(plan, ["3"])
    assert answer["descriptions"] == plan["manual"]
    assert answer["facts"] == [{"entity": "robot", "field": "movement", "value": "chaser"}]
    messages.validate("manual", {"version": 2, **answer})
    plan["facts"] = answer["facts"]  # a second answer keeps the first
    assert len(answered_manual(plan, ["1"])["facts"]) == 2


def test_every_line_typed_at_the_terminal_gets_a_command_or_a_reason_in_plain_words():
    import pytest
    from lwm_nodes.terminal_reviewer import parse_command

    taken = {
        "a": ("a", []), "approve": ("a", []), "reject": ("r", []), "abort": ("x", []), "stop": ("stop", []),
        "c 3:1 4:right": ("c", [(3, 1), (4, 3)]), "correct 2:Stay": ("c", [(2, 4)]), "i": ("i", []),
        "teach 2": ("i", [2]), "l -": ("l", []), "l 0:up": ("l", [(0, 0)]), "n": ("n", []), "next 7": ("n", [7]),
        "s 2": ("s", [2]), "q 1": ("q", ["1"]), "m": ("m", []), "restart": ("restart", []), "": ("", []),
    }  # fmt: skip
    for line, parsed in taken.items():
        assert parse_command(line) == parsed, line
    refused = {
        "c hello": "a correction is STEP:ACTION", "c 3:sideways": "a correction is STEP:ACTION",
        "c": "say which steps to correct", "i abc": "it is a number, e.g. i 2", "n x": "e.g. n 7",
        "s": "s takes a state number", "l 1": "a label is STATE:ACTION", "q": "q takes a choice",
        "a now": "a takes nothing after it", "hello": "unknown command",
    }  # fmt: skip
    for line, reason in refused.items():
        with pytest.raises(ValueError) as caught:
            parse_command(line)
        said = str(caught.value)
        assert reason in said, (line, said)
        assert "invalid literal" not in said and "unpack" not in said, (line, said)


def test_a_plan_that_repeats_a_rejected_one_says_what_can_change_it():
    plan = {**messages.schema("plan")["examples"][0], "reason": "reject", "repeats": 2}
    said = [line for line in plan_text(plan).splitlines() if "plan 2" in line]
    assert said == [
        "the same moves as plan 2, which you rejected: rejecting alone changes nothing the agent has learnt. "
        "To change the plan, correct a step (c STEP:ACTION), teach it (i) or rewrite the manual (m)"
    ]
    assert "rejected" not in plan_text(messages.schema("plan")["examples"][0])
    page = plan_view(plan)["repeats_text"]  # the page's words, for its buttons rather than commands
    assert page.startswith("The same moves as plan 2, which you rejected") and "correct a step, teach it" in page
    assert plan_view(messages.schema("plan")["examples"][0])["repeats_text"] == ""


def _real_episodes(n_games: int):
    """Real Messenger episodes as a report carries them, with the game's spec: every other one played
    by the paper's simulated person (who mostly wins), the rest by random moves (which mostly die)."""
    import numpy as np

    from lwm_models.agent.expert import expert_actions, role_ids
    from lwm_models.data.splits import load_split
    from lwm_models.messenger.engine import grid_to_compact
    from lwm_models.messenger.env import MessengerEnv

    games = load_split("newall-test")
    rng = np.random.default_rng(0)
    for g in range(n_games):
        spec = games[g % len(games)]
        env = MessengerEnv(spec)
        obs, _ = env.reset(seed=g)
        observations, actions, reward, done, has = [obs.tolist()], [], 0.0, False, False
        while not done:
            if g % 2:
                a = int(expert_actions(grid_to_compact(obs)[None], role_ids(spec), len(actions) + 1, g)[0])
            else:
                a = int(rng.integers(5))
            carried_before = has
            obs, r, term, trunc, info = env.step(a)
            has = env.has_message
            observations.append(obs.tolist())
            actions.append(a)
            reward += r
            done = term or trunc
        outcome = "died" if not env.alive else "won" if env.won else "time_limit"
        yield spec, carried_before, {
            "review_id": f"newall-test:{g}:0", "plan_id": 2, "revisions": 1, "real_return": reward,
            "imagined_return": 1.5, "steps": len(actions), "outcome": outcome,
            "divergence": {"first_step": 1, "mean_cells": 1.0, "risk_steps": []}, "actions": actions,
            "observations": observations, "planned_observations": observations[:3],
        }  # fmt: skip


def test_a_report_says_how_the_real_episode_ended_and_what_the_avatar_touched():
    from lwm_models.agent.review_text import report_text

    ends = {"died": 0, "won": 0}
    for spec, carried, report in _real_episodes(120):
        text = report_text(report)
        if report["outcome"] in ends:
            ends[report["outcome"]] += 1
            roles = {e.identity: e.role for e in spec.entities}
            line = text.splitlines()[1]
            touched = line.split(", touching the ")[1].split(":")[0].split(" and the ")
            if report["outcome"] == "died":  # the enemy, or the goal without the message
                assert "enemy" in {roles[t] for t in touched} or (not carried and "goal" in {roles[t] for t in touched})
                assert line.startswith(f"the agent died at step {report['steps']}, touching the ")
            else:
                assert "goal" in {roles[t] for t in touched}, (line, roles)
        # The real episode beside the plan: start, the step they part, the end; every step with "all".
        titles = [line for line in text.splitlines() if line.startswith("real ") and line.endswith("imagined (plan 2)")]
        assert len(titles) == len({0, 1, report["steps"]})
        assert report_text(report, "all").count("imagined (plan 2)") == report["steps"] + 1
        assert text.endswith("m a new manual for this game")
    assert ends["died"] >= 5 and ends["won"] >= 1, ends


def test_a_plan_that_looks_worse_after_a_change_says_so_and_how_to_take_it_back():
    from lwm_models.agent.review_text import worse_text
    from lwm_models.agent.review_view import plan_view

    plan = copy.deepcopy(messages.schema("plan")["examples"][0])
    assert worse_text(plan) == "" and plan_view(plan)["worse_text"] == ""
    plan["worse"] = {"plan": 3, "after": "corrections", "death_share": 0.25, "return_mean": 0.8}
    messages.validate("plan", {"version": messages.version("plan"), **plan})
    said = worse_text(plan)
    assert said.startswith("this plan looks worse than plan 3, before your correction: its futures die 100% (were 25%)")
    assert said.endswith("u takes it back") and said in plan_text(plan)
    assert plan_view(plan)["worse_text"].endswith("undo takes it back")


def test_worse_is_judged_on_the_sampled_futures():
    from lwm_models.agent.agent import Plan
    from lwm_models.agent.review import worse_than

    def plan(plan_id: int, death: float, mean: float) -> Plan:
        p = Plan(**{k: v for k, v in messages.schema("plan")["examples"][0].items() if k in Plan.__dataclass_fields__})
        p.plan_id, p.futures = plan_id, {**p.futures, "death_share": death, "return_mean": mean}
        return p

    assert worse_than(plan(1, 0.25, 0.5), plan(2, 0.5, 0.5)) == {"plan": 1, "death_share": 0.25, "return_mean": 0.5}
    assert worse_than(plan(1, 0.25, 0.5), plan(2, 0.25, -0.1)) is not None  # the mean fell by 0.6
    assert worse_than(plan(1, 0.25, 0.5), plan(2, 0.375, 0.2)) is None  # one more future dies of 8: noise
