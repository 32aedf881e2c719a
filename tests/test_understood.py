"""What the world model understood of each entity, read back from imagined trajectories: movement
relative to the avatar, and what a contact did."""

from __future__ import annotations

import numpy as np

from lwm_models.agent.understood import describe, read_back

T = 8


def trajectory(end_reward: float = 0.0, touching: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The avatar stands at (2, 2); the airplane (2) comes toward it, the mage (3) moves away, the
    dog (4) stays. With end_reward, the last step's reward comes while entity `touching` is next
    to the avatar."""
    obs = np.zeros((T + 1, 4, 3), dtype=np.uint8)
    for t in range(T + 1):
        obs[t, 0] = (2, 2, max(3, 7 - t // 2))
        obs[t, 1] = (3, 5, min(9, 5 + t // 2))
        obs[t, 2] = (4, 8, 8)
        obs[t, 3] = (15, 2, 2)
    rewards = np.zeros(T + 1, dtype=np.float32)
    if touching is not None:
        obs[T - 1 :, touching, 1:] = (2, 3) if touching == 0 else (3, 3)
        for k, far in zip([c for c in range(3) if c != touching], [(9, 9), (9, 0)], strict=True):
            obs[T - 1 :, k, 1:] = far  # the others far away
        rewards[T] = end_reward
    return obs, rewards


def test_movement_is_read_from_where_each_entity_went():
    obs, rewards = trajectory()
    got = {e["identity"]: e for e in read_back(obs[None], rewards[None], np.array([T + 1]))}
    assert got["airplane"]["movement"] == "comes toward you" and got["airplane"]["closer"] >= 3
    assert got["mage"]["movement"] == "moves away from you" and got["mage"]["farther"] >= 2
    assert got["dog"]["movement"] == "stays put" and got["dog"]["closer"] + got["dog"]["farther"] == 0
    assert all(e["role"] == "not seen" for e in got.values())
    assert describe(got["dog"]) == "stays put; its role not seen in these futures"


def test_a_contact_says_the_role_only_of_the_entity_touched():
    dies, r1 = trajectory(-1.0, touching=0)
    dies[T, 3] = 0  # the avatar is gone on death
    picks, r2 = trajectory(0.5, touching=1)
    wins, r3 = trajectory(1.0, touching=2)
    obs, rewards = np.stack([dies, picks, wins]), np.stack([r1, r2, r3])
    got = {e["identity"]: e for e in read_back(obs, rewards, np.array([T + 1] * 3))}
    assert got["airplane"]["role"] == "you died touching it" and got["airplane"]["contacts"]["death"] == 1
    assert got["mage"]["role"] == "gives you the message" and got["mage"]["contacts"]["message"] == 1
    assert got["dog"]["role"] == "the goal" and got["dog"]["contacts"]["win"] == 1
    assert describe(got["airplane"]).endswith("you died touching it (1 time)")


def test_a_plan_carries_what_its_futures_show_and_the_page_and_terminal_say_it():
    from lwm_models import messages
    from lwm_models.agent.review_text import plan_text
    from lwm_models.agent.review_view import plan_view

    plan = dict(messages.schema("plan")["examples"][0])
    obs, rewards = trajectory()
    plan["understood"] = read_back(obs[None], rewards[None], np.array([T + 1]))
    messages.validate("plan", plan)  # the schema knows the field
    view = plan_view(plan)
    assert [i["identity"] for i in view["imagined"]] == ["airplane", "mage", "dog"]
    assert view["imagined"][0]["said"].startswith("comes toward you")
    assert "imagined airplane: comes toward you" in plan_text(plan)
