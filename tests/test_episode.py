"""Episode ids: the one place that reads and writes `split:index:seed[#attempt]`."""

from __future__ import annotations

import pytest

from lwm_models.data.episode import Episode, game_of
from lwm_models.data.session import GameSession
from lwm_models.errors import LwmError


def test_an_id_reads_back_as_the_episode_it_names():
    first = Episode("newall-test", 4, 17)
    assert first.id == "newall-test:4:17" and Episode.parse(first.id) == first
    again = first.restarted().restarted()
    assert again.id == "newall-test:4:17#3" and Episode.parse(again.id) == again
    assert again.game == game_of(again.id) == "newall-test:4" and again.next() == Episode("newall-test", 4, 18)


@pytest.mark.parametrize("bad", ["", "newall-test:4", "newall-test:4:x", "newall-test:4:1#0", "a:b:c:d", "x:1:2#"])
def test_what_is_no_episode_id_is_refused_in_words(bad):
    with pytest.raises(LwmError, match="episode id|counts from 1"):
        Episode.parse(bad)


def test_a_restarted_episode_starts_from_the_same_board_as_a_new_attempt():
    session = GameSession("newall-test", 2)
    with pytest.raises(LwmError, match="no episode to restart"):
        session.reset(restart=True)
    first = session.reset(5)
    session.step(3)
    again = session.reset(restart=True)
    assert (first["episode_id"], first["attempt"]) == ("newall-test:2:5", 1)
    assert (again["episode_id"], again["attempt"], again["t"]) == ("newall-test:2:5#2", 2, 0)
    assert again["observation"] == first["observation"] and again["seed"] == 5
    assert session.reset(restart=True)["episode_id"] == "newall-test:2:5#3"
    assert session.reset(6)["episode_id"] == "newall-test:2:6"  # the next episode is a first attempt
