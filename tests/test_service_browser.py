"""The dashboard in a real browser: Debian's headless Chromium driven by selenium through
chromedriver, against a real uvicorn server on loopback (in a thread of its own, so the
browser's blocking calls never stall it), judged by the simulated twins.

``make test`` installs chromium and chromium-driver when they are missing
(``.ci/ensure-chromium``); without them this test is skipped and says why. The page's
screenshot is saved to ``tests/artifacts/dashboard.png`` (ignored by git).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from anyio.from_thread import BlockingPortal, start_blocking_portal

from drivebus import AxisState
from drivebus.service import Service, TokenStore
from service_rig import ROOT, TOKENS, running, token_file, until

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

CHROMIUM = shutil.which("chromium")
CHROMEDRIVER = shutil.which("chromedriver")
ARTIFACTS = ROOT / "tests" / "artifacts"

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="needs Debian's chromium and chromium-driver: `sh .ci/ensure-chromium` as root "
           "(make test runs it) or `apt-get install chromium chromium-driver`",
)


@pytest.fixture
def browser() -> Iterator[webdriver.Chrome]:
    """Headless Chromium with a fresh profile, through Debian's chromedriver."""
    assert CHROMIUM is not None and CHROMEDRIVER is not None
    with tempfile.TemporaryDirectory(prefix="drivebus-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage", f"--user-data-dir={profile}",
                    "--window-size=1280,1100"):
            options.add_argument(arg)
        driver = webdriver.Chrome(options=options,
                                  service=webdriver.ChromeService(executable_path=CHROMEDRIVER))
        try:
            yield driver
        finally:
            driver.quit()


def wait(driver: webdriver.Chrome, check: Callable[[webdriver.Chrome], object],
         message: str) -> None:
    """Wait for a condition on the page (a hang guard of 20 s, not a figure)."""
    WebDriverWait(driver, 20, poll_frequency=0.05).until(check, message)


def text(driver: webdriver.Chrome, element_id: str) -> str:
    return str(driver.find_element(By.ID, element_id).text)


class Machine:
    """The service's twins and axes, looked at from the test's thread: every check runs
    in the service's event loop (through the portal), at its axis polls."""

    def __init__(self, portal: BlockingPortal, svc: Service) -> None:
        self.portal, self.svc = portal, svc
        self.twins = svc.session.machine.sim_drives

    def until(self, check: Callable[[], bool], what: str) -> None:
        """Wait until ``check()`` (run in the loop) holds."""
        self.portal.call(lambda: until(self.svc, check, what=what))

    def state(self, axis: str) -> AxisState:
        """The axis's state (call inside checks, or through ``now``)."""
        return self.svc.session.axis(axis).state

    def at_rest(self, *axes: str) -> bool:
        """Every named twin (all if none) at rest and its axis out of motion."""
        names = axes or tuple(self.twins)
        return not any(self.twins[n].is_moving() for n in names) and all(
            self.state(n) in (AxisState.STANDSTILL, AxisState.DISABLED) for n in names)

    def now(self, fn: Callable[[], object]) -> object:
        """``fn()`` evaluated in the service's loop."""
        return self.portal.call(fn)


def test_the_dashboard_shows_live_positions_jogs_and_estops(browser: webdriver.Chrome) -> None:
    with (
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running()) as (svc, client),
    ):
        m = Machine(portal, svc)
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: text(d, "conn") == "live", "the page never went live")
        wait(browser, lambda d: text(d, "pos-x") == "12.000", "no position for x")
        assert text(browser, "machine") == "demo"

        # move-to from the page; the table's position changes as the axis is polled
        browser.find_element(By.ID, "target-x").send_keys("300")
        browser.find_element(By.XPATH, "//tr[@id='row-x']//button[text()='Move']").click()
        seen: set[str] = set()

        def live_positions(d: webdriver.Chrome) -> bool:
            if text(d, "state-x") == "DiscreteMotion":
                seen.add(text(d, "pos-x"))
            return len(seen) >= 5

        wait(browser, live_positions, "x's position did not change live on the page")
        assert m.now(m.twins["x"].is_moving)
        browser.find_element(By.ID, "stop-x").click()
        m.until(lambda: m.at_rest("x"), "x did not stop")

        # hold-to-jog: moves while held (fed beyond its TTL), stops when released
        z0 = int(m.now(m.twins["z"].position))  # type: ignore[call-overload]
        jog = browser.find_element(By.ID, "jog-plus-z")
        ActionChains(browser).click_and_hold(jog).perform()
        # 5 mm/s with a 0.5 s TTL: 4 mm (1000 pulses/4 mm) needs feeds past the first TTL
        m.until(lambda: m.twins["z"].position() - z0 >= 1000, "z did not keep jogging")
        assert "held" in str(jog.get_attribute("class"))
        ActionChains(browser).release(jog).perform()
        m.until(lambda: m.at_rest("z"), "z did not stop when the jog button was released")
        wait(browser, lambda d: text(d, "state-z") == "Standstill", "the page missed the stop")

        # a connection lost mid-jog stops the axis too
        ActionChains(browser).click_and_hold(browser.find_element(By.ID, "jog-minus-z")).perform()
        m.until(lambda: m.twins["z"].is_moving(), "z did not jog down")
        browser.get("about:blank")  # the page (and its WebSocket) is gone
        m.until(lambda: m.at_rest("z"), "z kept jogging after the page went away")

        # the e-stop button halts every axis
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: text(d, "conn") == "live", "the page did not come back")
        portal.call(lambda: client.post("/api/axes/r/move", json={"target": 700.0}))
        browser.find_element(By.ID, "target-x").send_keys("390")
        browser.find_element(By.XPATH, "//tr[@id='row-x']//button[text()='Move']").click()
        m.until(lambda: m.twins["x"].is_moving() and m.twins["r"].is_moving(),
                "x and r did not start")
        time.sleep(0.3)  # let the plot draw some motion for the screenshot
        browser.find_element(By.ID, "estop").click()
        m.until(m.at_rest, "the e-stop left an axis moving")
        wait(browser, lambda d: "e-stop done" in text(d, "events"), "no e-stop on the page")
        wait(browser, lambda d: text(d, "state-x") != "DiscreteMotion", "x still moving")

        ARTIFACTS.mkdir(exist_ok=True)
        shot = ARTIFACTS / "dashboard.png"
        assert browser.save_screenshot(str(shot))
        print(f"dashboard screenshot: {shot}")
        assert shot.stat().st_size > 10_000


def test_the_dashboard_asks_for_a_token_when_the_service_has_them(
    browser: webdriver.Chrome, tmp_path: Path
) -> None:
    tokens = TokenStore.load(token_file(tmp_path))
    with (
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running(tokens=tokens)) as (svc, _),
    ):
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: d.find_element(By.ID, "login").is_displayed(),
             "no token prompt")
        assert text(browser, "conn") != "live"
        browser.find_element(By.ID, "token").send_keys(TOKENS["viewer"][1])
        browser.find_element(By.XPATH, "//form[@id='login']//button").click()
        wait(browser, lambda d: text(d, "conn") == "live", "the token did not let it in")
        assert text(browser, "who") == "viewer (read)"
        wait(browser, lambda d: text(d, "pos-x") == "12.000", "no live axes")
