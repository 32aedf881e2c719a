"""The review page says what holds now (issue 59, item 8), in a real browser (headless Chromium
driven by Selenium) against the real system: a new episode starts with an empty corrections box and
the History on the review under review; the states a label request asks about come in ascending
order; an answer the planner kept while it was starting stops saying so once the review opens; the
boards' symbols and marks have a key beside the plan and the report. One system serves the file:
each test starts from the review the system is on, whatever the tests before it left.
Screenshots go to the test's directory (and to LWM_SCREENSHOTS)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
import urllib.request
from collections.abc import Iterator

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("selenium.webdriver")
from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException  # noqa: E402
from selenium.webdriver.common.keys import Keys  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402
from test_review_page import (  # noqa: E402 (after the skips: it needs Chromium and Selenium)
    approve,
    approve_until_reported,
    browser,  # noqa: F401 (the headless Chromium fixture)
    node_pid,
    shoot,
    start_page_system,
)

pytestmark = pytest.mark.system

WAIT_S = 180  # generous: the machine may be shared (another test system, a training job)


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    """One launcher with the page for the file; the reviewer named, so answers apply at once."""
    yield from start_page_system(tmp_path_factory.mktemp("page_text"), "--reviewer", "alice")


class Page:
    """The review page in the browser, with the waits the tests share."""

    def __init__(self, driver, url: str) -> None:
        self.driver = driver
        driver.get(url)
        self.wait = WebDriverWait(driver, WAIT_S, poll_frequency=0.3)
        self.wait.until(lambda _: self.text("plan-title").startswith("plan ") and not self.off("reject"))

    def text(self, element: str) -> str:
        return self.driver.find_element("id", element).text

    def off(self, button: str) -> bool:
        return bool(self.driver.find_element("id", button).get_attribute("disabled"))

    def review(self) -> str:
        """The review of the plan shown ("plan 2 of review ID (reason), ...")."""
        return self.text("plan-title").split(" of review ")[1].split()[0]

    def plan_id(self) -> int:
        return int(self.text("plan-title").split()[1])

    def next_episode(self) -> str:
        """Starts the next episode and waits for its first plan; returns its review id."""
        before = self.review()
        self.driver.find_element("id", "next-episode").click()
        self.wait.until(lambda _: " started" in self.text("episode-message"))
        self.wait.until(lambda _: self.review() != before and not self.off("reject"))
        return self.review()

    def chosen_history(self) -> str:
        """The review the History shows the records of (its chosen row)."""

        def read(_) -> str | bool:
            try:  # the History is drawn anew as records come: a row found may be gone when read
                return self.driver.find_element("css selector", "#reviews tr.chosen td").text
            except (NoSuchElementException, StaleElementReferenceException):
                return False

        return self.wait.until(read)


@pytest.fixture()
def page(system, browser) -> Page:  # noqa: F811 (the fixture imported above)
    url, _, _ = system
    return Page(browser, url)


def test_a_plan_that_repeats_a_rejected_one_says_what_can_change_it(system, page):
    """A reject changes nothing the agent has learnt: when the plan after it makes the same moves,
    the page says so under the plan's title and names what can change it; a plan that moves
    otherwise says nothing of the kind. (In this system's seeds the plans after a reject move
    otherwise; test_review_loop.py has plans that repeat, and test_review_text.py the words.)"""
    url, tmp_path, _ = system
    seen = set()
    for _ in range(6):
        before = json.load(urllib.request.urlopen(url + "api/state", timeout=10))["plan"]
        page.driver.find_element("id", "reject").click()
        shown = before["plan_id"]
        page.wait.until(lambda _, shown=shown: page.plan_id() > shown and not page.off("reject"))
        now = json.load(urllib.request.urlopen(url + "api/state", timeout=10))["plan"]
        same = now["actions"] == before["actions"]
        said = page.text("repeats")
        if same:
            assert said.startswith(f"The same moves as plan {before['plan_id']}, which you rejected"), said
            assert "correct a step, teach it or rewrite the manual" in said
            shoot(page.driver, tmp_path, "review_page_plan_repeats.png")
        else:
            assert said == "", said
        seen.add(same)
        if seen == {True, False}:
            break


def test_a_new_episode_starts_with_empty_corrections_and_the_history_on_it(system, page):
    """The corrections box kept "4:1" from the previous episode, and the History stayed on the
    review the page first showed. Now a new review empties the box and the History follows it;
    a review the person chose in the History stays chosen until the next review starts."""
    first = page.review()
    assert page.chosen_history() == first
    # A correction of step 1, taken: the box keeps what was sent while this review is open.
    url, tmp_path, _ = system
    plan = json.load(urllib.request.urlopen(url + "api/state", timeout=10))["plan"]
    sent = f"1:{(plan['actions'][0] + 2) % 5}"  # another action than the plan's
    box = page.driver.find_element("id", "corrections")
    box.clear()
    box.send_keys(sent)
    page.driver.find_element("id", "correct").click()
    page.wait.until(lambda _: f"corrections of plan {plan['plan_id']} taken" in page.text("message"))
    page.wait.until(lambda _: page.plan_id() > plan["plan_id"])
    assert box.get_attribute("value") == sent

    second = page.next_episode()
    assert second != first
    assert box.get_attribute("value") == "", "the last episode's corrections were left in the box"
    page.wait.until(lambda _: page.chosen_history() == second)
    shoot(page.driver, tmp_path, "review_page_next_episode_fresh.png")

    # The person looks at the earlier review: a new plan of this one does not take it away.
    row = next(r for r in page.driver.find_elements("css selector", "#reviews tr.review") if r.text.startswith(first))
    row.click()
    page.wait.until(lambda _: page.chosen_history() == first)
    shown = page.plan_id()
    page.driver.find_element("id", "reject").click()
    page.wait.until(lambda _: page.plan_id() > shown and not page.off("reject"))
    assert page.chosen_history() == first
    # The next review is followed again.
    third = page.next_episode()
    page.wait.until(lambda _: page.chosen_history() == third)


def test_the_states_asked_about_come_in_ascending_order(system, page):
    """The states of a label request were walked as "state 3", then "state 0". Now the panel, the
    keys and the overview all go by state number, as the terminal lists them."""
    _, tmp_path, _ = system
    page.driver.find_element("id", "imitate").click()
    page.wait.until(lambda _: page.text("labels-title").startswith("label request "))
    n = int(page.text("labels-title").split(": ")[1].split()[0])
    assert n >= 2, page.text("labels-title")

    def state() -> int:
        return int(page.text("label-state-info").split()[0])

    walked = [state()]
    for _ in range(n - 1):
        page.driver.find_element("tag name", "body").send_keys("n")
        walked.append(state())
    assert walked == list(range(n)), walked
    # The overview's tiles, left to right, are the same states in the same order.
    tiles = page.driver.execute_script("return tiles.xy.map(([x, y]) => x)")
    assert tiles == list(range(n)), tiles
    overview = page.driver.find_element("id", "label-overview")
    side, gap = page.driver.execute_script("return [tiles.side, tiles.gap]")
    for k in (n - 1, 0):  # a click on the k-th tile shows state k
        page.driver.execute_script(
            "const r = arguments[0].getBoundingClientRect(), at = {clientX: r.left + arguments[1], clientY: r.top + 5};"
            "arguments[0].dispatchEvent(new MouseEvent('click', at));",
            overview,
            k * (side + gap) + side // 2,
        )
        assert state() == k
    # A label moves on to the next state by number.
    page.driver.find_element("tag name", "body").send_keys(Keys.ARROW_RIGHT)
    assert state() == 1 and "1 of " in page.text("label-count")
    shoot(page.driver, tmp_path, "review_page_states_in_order.png", "labels")
    shown = page.plan_id()
    page.driver.find_element("id", "stop-teaching").click()
    page.wait.until(lambda _: page.plan_id() > shown and not page.driver.find_element("id", "labels").is_displayed())


@contextlib.contextmanager
def stopped(pid: int) -> Iterator[None]:
    """A node held (SIGSTOP) meanwhile, and let go (SIGCONT) after."""
    os.kill(pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def test_an_answer_kept_while_the_planner_starts_stops_saying_so_once_the_review_opens(system, page):
    """An answer sent while a restarted planner has not opened its review yet is kept for it ("kept
    until review ... opens (the planner is starting)"). That stayed on the page after the review's
    next plan came. The environment is held while the planner restarts, so the planner cannot open
    the review until the test lets it go: the answer is kept every time, not by chance."""
    _, tmp_path, launcher = system
    review, shown = page.review(), page.plan_id()
    planner = node_pid(launcher, "lwm_nodes.planner_node")
    with stopped(node_pid(launcher, "lwm_nodes.env_node")):
        os.kill(planner, signal.SIGKILL)
        page.wait.until(lambda _: node_pid(launcher, "lwm_nodes.planner_node") not in (None, planner))
        # The restarted planner is up (it says so on /diagnostics) but has no review without the game.
        page.wait.until(
            lambda _: "the planner stopped and started again; it says: waiting for an episode" in page.text("notice")
        )
        page.driver.find_element("id", "reject").click()
        page.wait.until(lambda _: f"kept until review {review} opens (the planner is starting)" in page.text("message"))
        shoot(page.driver, tmp_path, "review_page_answer_kept.png", "message")
    # The review opens, takes the kept reject, and its next plan comes: the words no longer hold.
    page.wait.until(lambda _: page.plan_id() > shown)
    said = page.text("message")
    assert "kept until" not in said and f"opened review {review}" in said, said
    assert page.driver.find_element("id", "message").value_of_css_property("color") == "rgba(102, 102, 102, 1)"
    shoot(page.driver, tmp_path, "review_page_answer_kept_then_taken.png", "message")
    # What the restarted planner was sent again of what it took before is no error of anyone's.
    time.sleep(3)  # its diagnostics (every second) would carry such an error to the page
    assert "taken before" not in page.text("notice"), page.text("notice")


def test_the_boards_symbols_and_marks_have_a_key(system, page):
    """The report's frames showed a green outlined square and a yellow '&' that nothing explained.
    Beside the plan and beside the report, a key says what '@', '&' and '*' are and what the died
    and won marks are; the '&' chip has the colour of the '&' cell on the boards."""
    _, tmp_path, _ = system
    key = [e.text for e in page.driver.find_elements("css selector", "#plan-key div")]
    expected = [
        "@\nyou",
        "&\nyou, carrying the message",
        "*\ntwo entities on one cell",
        "where you died",
        "where you won",
    ]
    assert key == expected, key
    approved = page.text("plan-title")
    approve(page.driver)
    approve_until_reported(page.driver, page.wait, approved)
    key = [e.text for e in page.driver.find_elements("css selector", "#report-key div")]
    assert key == expected, key
    carrying = page.driver.find_elements("css selector", "#report-key .chip")[1]
    assert carrying.value_of_css_property("background-color") == "rgba(255, 200, 0, 1)"  # the '&' cell's yellow
    # The marks in the key are drawn: a green square's edge, a red one's.
    edge = page.driver.execute_script(
        "return ['dies', 'wins'].map((e) => Array.from("
        "document.querySelector('#report-key canvas.mark-' + e).getContext('2d').getImageData(2, 9, 1, 1).data))"
    )
    assert edge == [[204, 0, 0, 255], [0, 119, 0, 255]], edge
    # The report's last step, where a death or a win is marked.
    page.driver.execute_script(
        "const s = document.getElementById('report-step'); s.value = s.max; s.dispatchEvent(new Event('input'))"
    )
    shoot(page.driver, tmp_path, "review_page_report_key.png", "report")
