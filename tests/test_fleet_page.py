"""The fleet page in a real browser (headless Chromium driven by Selenium) against a real fleet of
two agents (`--agents 2 --page PORT`): both agents appear in the queue waiting for the person; a
manual missing a description is refused in plain words; one manual written there re-plans both
agents under the new version; each agent's link opens its own review page with its plan.
Screenshots go to the test's directory (and to LWM_SCREENSHOTS)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
from lwm_nodes import domains  # noqa: E402

CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
if not (CHROMIUM and DRIVER):
    pytest.skip("no Chromium (apt-get install chromium chromium-driver)", allow_module_level=True)
pytest.importorskip("selenium.webdriver")
from selenium.common.exceptions import StaleElementReferenceException  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402
from test_review_page import browser, free_port  # noqa: E402, F401 (browser: the same headless Chromium fixture)

pytestmark = pytest.mark.system

MANUAL = [
    "the plane chases you and it is deadly.",
    "the ball has the message and runs away from you.",
    "the robot is the goal and it never moves.",
]


@pytest.fixture()
def fleet(tmp_path):
    port = free_port()
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
    }
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--agents", "2", "--page", str(port), "--quiet"]
    cmd += ["--iterations", "1", "--futures", "2", "--log-dir", str(tmp_path / "logs")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    pages = {}
    for line in proc.stdout:
        if "PAGE " in line:
            who = line.split("]")[0].strip("[")
            pages[who] = line.split(" at ")[-1].strip()
        if "nodes ready" in line or proc.poll() is not None:
            break
    assert pages.get("fleet_page") == f"http://127.0.0.1:{port}/", pages
    assert pages.get("agent2/human") == f"http://127.0.0.1:{port + 2}/", pages
    yield pages, tmp_path
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out


def rows(driver) -> dict[str, list[str]]:
    """The queue as shown: agent -> its cells' text."""
    return driver.execute_script(
        """const out = {};
        for (const tr of document.querySelectorAll('#queue tbody tr'))
          out[tr.dataset.agent] = [...tr.children].map((td) => td.textContent);
        return out;"""
    )


def shot(driver, tmp_path: Path, name: str) -> None:
    driver.save_screenshot(str(tmp_path / name))
    if os.environ.get("LWM_SCREENSHOTS"):
        driver.save_screenshot(str(Path(os.environ["LWM_SCREENSHOTS"]) / name))


def test_one_manual_on_the_fleet_page_replans_every_agent(fleet, browser):  # noqa: F811 (the fixture)
    pages, tmp_path = fleet
    browser.get(pages["fleet_page"])
    wait = WebDriverWait(browser, 240, poll_frequency=0.5)
    # One read of the table per poll: two reads could see it empty (all() of nothing is true) and
    # then filled, before any agent waits.
    wait.until(lambda d: len(shown := rows(d)) == 2 and all("waits for your answer" in r[2] for r in shown.values()))
    first = rows(browser)
    assert all(r[4] == "v1" and "(manual v1)" in r[3] for r in first.values()), first
    shot(browser, tmp_path, "fleet_page_queue.png")

    # A manual with a description left out: refused, in words, and nothing changes.
    browser.find_element("id", "d0").send_keys(MANUAL[0])
    browser.find_element("id", "reviewer-name").send_keys("alice")
    browser.find_element("id", "send").click()
    message = browser.find_element("id", "message")
    wait.until(lambda d: message.text.startswith("refused"))
    assert "Traceback" not in message.text and len(message.text) < 400, message.text

    for box, text in zip(("d1", "d2"), MANUAL[1:], strict=True):
        browser.find_element("id", box).send_keys(text)
    browser.find_element("id", "send").click()
    wait.until(lambda d: "manual taken for" in message.text)
    assert "agent1 (v2)" in message.text and "agent2 (v2)" in message.text, message.text

    # Both agents re-plan under the fleet's manual: each row's plan says version 2.
    def replanned(d) -> bool:
        shown = rows(d)
        return len(shown) == 2 and all("(manual v2)" in r[3] and r[4] == "v2" for r in shown.values())

    wait.until(replanned)
    shot(browser, tmp_path, "fleet_page_two_agents.png")

    # Each agent's link opens its own review page, with its plan under the new manual.
    # The table is redrawn as the agents report, so a row found may be gone by the click: find it again.
    clicking = WebDriverWait(browser, 30, poll_frequency=0.2, ignored_exceptions=(StaleElementReferenceException,))
    clicking.until(lambda d: d.find_element("css selector", "tr[data-agent='agent2'] a").click() or True)
    browser.switch_to.window(browser.window_handles[-1])
    assert browser.current_url == pages["agent2/human"]
    wait.until(
        lambda d: (
            "plan" in d.find_element("id", "plan-title").text.lower()
            and "no plan" not in d.find_element("id", "plan-title").text
        )
    )
    wait.until(lambda d: "v2" in d.find_element("id", "manual-version").text)
    shot(browser, tmp_path, "fleet_page_agent2.png")
