"""The review page in a real browser (headless Chromium driven by Selenium) against the real
system: the plan appears drawn, a description edited on the page becomes a new manual version
and a plan imagined under it, an approval from the page is executed and its report appears.
Screenshots go to the test's directory (and to LWM_SCREENSHOTS, for the README's pictures)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
if not (CHROMIUM and DRIVER):
    pytest.skip(
        "no Chromium: install it with `apt-get install chromium chromium-driver` (.ci/run does when CI=true)",
        allow_module_level=True,
    )
webdriver = pytest.importorskip("selenium.webdriver")
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture()
def page_system(tmp_path):
    port = free_port()
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(1 + (os.getpid() + 33) % 100),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_LOG_DIR": str(tmp_path / "roslog"),
    }
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--page", str(port), "--quiet", "--iterations", "2"]
    cmd += ["--log-dir", str(tmp_path / "logs"), "--ledger", str(tmp_path / "ledger.sqlite")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    url = None
    for line in proc.stdout:
        if "PAGE review page at" in line:
            url = line.split(" at ")[-1].strip()
        if "nodes ready" in line or proc.poll() is not None:
            break
    assert url == f"http://127.0.0.1:{port}/", "the launcher printed no page address"
    yield url, tmp_path
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out


@pytest.fixture()
def browser():
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,1000"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
    yield driver
    driver.quit()


def painted_cells(driver, canvas: str) -> int:
    """Cells of a canvas whose centre is not the empty-cell grey: the board is drawn, not blank."""
    return driver.execute_script(
        """const c = document.getElementById(arguments[0]), ctx = c.getContext("2d"), s = c.width / 10;
        let n = 0;
        for (let r = 0; r < 10; r++) for (let k = 0; k < 10; k++) {
          const p = ctx.getImageData((k + 0.5) * s, (r + 0.5) * s, 1, 1).data;
          if (!(p[0] === 245 && p[1] === 245 && p[2] === 245)) n++;
        }
        return n;""",
        canvas,
    )


def shoot(driver, tmp_path: Path, name: str) -> None:
    driver.save_screenshot(str(tmp_path / name))
    if os.environ.get("LWM_SCREENSHOTS"):
        shutil.copy(tmp_path / name, Path(os.environ["LWM_SCREENSHOTS"]) / name)


def test_review_in_the_browser(page_system, browser):
    url, tmp_path = page_system
    browser.get(url)
    wait = WebDriverWait(browser, 120, poll_frequency=0.3)
    title = lambda: browser.find_element("id", "plan-title").text  # noqa: E731
    wait.until(lambda _: title().startswith("plan 1 "))
    assert "manual v1" in title() and painted_cells(browser, "board") >= 3  # avatar and entities
    assert len(browser.find_elements("css selector", "#legend div")) == 3
    shoot(browser, tmp_path, "review_page_plan.png")

    # Language feedback from the page: the enemy's description reworded.
    box = browser.find_element("id", "d2")
    box.clear()
    box.send_keys("the airplane is a deadly enemy that chases you.")
    browser.find_element("id", "send-manual").click()
    wait.until(lambda _: "manual v2" in title())
    legend = browser.find_element("id", "legend").text
    assert "airplane: enemy, chaser" in legend
    shoot(browser, tmp_path, "review_page_new_manual.png")

    browser.find_element("id", "approve").click()
    wait.until(lambda _: browser.find_element("id", "report").is_displayed())
    report = browser.find_element("id", "report-title").text
    assert report.startswith("report, plan ") and "real return" in report
    assert painted_cells(browser, "real") >= 2 and painted_cells(browser, "planned") >= 2
    shoot(browser, tmp_path, "review_page_report.png")

    # Another origin cannot answer through the reviewer's browser.
    request = urllib.request.Request(
        url + "api/feedback",
        data=json.dumps({"decision": "approve"}).encode(),
        headers={"Content-Type": "application/json", "Origin": "http://evil.example"},
    )
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(request, timeout=10)
    assert refused.value.code == 403
