"""The dashboard in a real browser: Debian's headless Chromium driven by selenium through
chromedriver, against a real uvicorn server on loopback (in a thread of its own, so the
browser's blocking calls never stall it), judged by the simulated twins.

``make test`` installs chromium and chromium-driver when they are missing
(``.ci/ensure-chromium``); without them this test is skipped and says why. The page's
screenshots are saved under ``tests/artifacts/`` (ignored by git).
"""

from __future__ import annotations

import bisect
import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from anyio.from_thread import BlockingPortal, start_blocking_portal

from browser_rig import chromium, drawn_held, needs_chromium, screenshot, wait, webdriver
from drivebus import AxisState
from drivebus.service import Service, TokenStore
from service_rig import TOKENS, auth, running, token_file, until

ActionChains = pytest.importorskip("selenium.webdriver.common.action_chains").ActionChains
By = pytest.importorskip("selenium.webdriver.common.by").By
Select = pytest.importorskip("selenium.webdriver.support.select").Select

pytestmark = needs_chromium


@pytest.fixture
def browser() -> Iterator[webdriver.Chrome]:
    """Headless Chromium with a fresh profile, through Debian's chromedriver."""
    with chromium() as driver:
        yield driver


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

        screenshot(browser, "dashboard")


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


def websockets_opened(driver: webdriver.Chrome) -> list[str]:
    """The WebSockets the page opened since the last look (a browser that logs)."""
    urls = []
    for entry in driver.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        if msg.get("method") == "Network.webSocketCreated":
            urls.append(msg["params"]["url"])
    return urls


def test_with_tokens_the_estop_says_it_is_disabled_and_why_until_a_token_lets_it_act(
    tmp_path: Path,
) -> None:
    tokens = TokenStore.load(token_file(tmp_path))
    with (
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running(tokens=tokens)) as (svc, client),
        chromium(offline=True) as browser,
    ):
        m = Machine(portal, svc)
        r = portal.call(lambda: client.post("/api/axes/x/move", headers=auth("alice"),
                                            json={"target": 390.0, "speed": 20.0}))
        assert r.status_code == 202, r.text
        m.until(lambda: m.twins["x"].is_moving(), "x did not start")

        browser.get(f"{svc.url}/")
        wait(browser, lambda d: d.find_element(By.ID, "login").is_displayed(),
             "no token prompt")
        # asked at once: from the service's 401, with no WebSocket left to time out
        assert websockets_opened(browser) == []
        assert text(browser, "conn") == "token needed"
        estop = browser.find_element(By.ID, "estop")
        assert not estop.is_enabled()
        assert text(browser, "estop-why") == "log in first: this service needs a token"
        assert "E-STOP disabled" in str(estop.get_attribute("title"))
        assert m.now(m.twins["x"].is_moving)  # nothing pretended to stop it

        browser.find_element(By.ID, "token").send_keys("not-a-token-0123456789")
        browser.find_element(By.XPATH, "//form[@id='login']//button").click()
        wait(browser, lambda d: "Unauthorized" in text(d, "login-error"),
             "a wrong token was not refused on the form")
        assert not estop.is_enabled() and websockets_opened(browser) == []

        browser.find_element(By.ID, "token").clear()
        browser.find_element(By.ID, "token").send_keys(TOKENS["viewer"][1])
        browser.find_element(By.XPATH, "//form[@id='login']//button").click()
        wait(browser, lambda d: text(d, "conn") == "live", "the token did not let it in")
        assert not browser.find_element(By.ID, "toast").is_displayed()  # no stale toast
        assert not browser.find_element(By.ID, "login").is_displayed()
        assert estop.is_enabled() and text(browser, "estop-why") == ""
        assert len(websockets_opened(browser)) == 1
        estop.click()  # a read token may press it
        m.until(lambda: m.at_rest("x"), "the e-stop did not stop x")
        wait(browser, lambda d: "e-stop done" in text(d, "events"), "no e-stop on the page")
        assert not browser.find_element(By.ID, "toast").is_displayed()


def test_the_dashboard_has_a_favicon(browser: webdriver.Chrome) -> None:
    with (
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running()) as (svc, client),
    ):
        r = portal.call(lambda: client.get("/favicon.ico"))
        assert r.status_code == 200 and r.headers["content-type"] == "image/x-icon"
        assert r.content[:4] == b"\x00\x00\x01\x00"  # an ICO file's header
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: text(d, "conn") == "live", "the page never went live")
        icon = browser.execute_async_script("""
            const done = arguments[arguments.length - 1];
            const link = document.querySelector("link[rel=icon]");
            fetch(link.href).then((r) => done([link.href, r.status,
                                               r.headers.get("content-type")]));""")
        assert icon == [f"{svc.url}/favicon.ico", 200, "image/x-icon"]


def test_the_dashboard_charts_what_the_service_recorded() -> None:
    """Every point the page plots for an axis is a status the service recorded, at the
    same poll time, with the same position; the Record button gives the report."""
    with (
        chromium(height=1700) as browser,
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running()) as (svc, client),
    ):
        m = Machine(portal, svc)
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: text(d, "conn") == "live", "the page never went live")
        Select(browser.find_element(By.ID, "window")).select_by_value("10")  # finer
        browser.find_element(By.ID, "record").click()
        wait(browser, lambda d: d.find_element(By.ID, "record").get_attribute("data-id"),
             "the Record button started no recording")
        rec_id = str(browser.find_element(By.ID, "record").get_attribute("data-id"))
        portal.call(lambda: client.post("/api/machine/group-move", json={
            "targets": {"x": 150.0, "y": 60.0, "z": 40.0, "r": 270.0}}))
        # the chart's points of x while it moved (the chart's data and the page's states
        # of the same polls): they come while it moves, whether or not the table still
        # shows the motion when the browser is asked
        moving_points = """
            const n = DrivebusCharts.registry.get('axis-x').data()[0].length;
            return state.series.get('x').state.slice(-n)
                .filter((s) => s === 'DiscreteMotion').length;"""
        wait(browser, lambda d: int(d.execute_script(moving_points)) >= 8,
             "the chart of x did not follow the move")
        screenshot(browser, "dashboard-move")
        m.until(lambda: m.at_rest("x", "y", "z", "r"), "the group move did not end")
        wait(browser, lambda d: text(d, "state-x") == "Standstill", "the page missed the end")
        browser.find_element(By.ID, "pause").click()  # the charts hold still to be read
        telling = checked = 0
        # position and velocity (the BHSS of y reports none): each poll held until the next
        for name, series in (("x", 1), ("x", 2), ("y", 1), ("r", 1), ("r", 2)):
            drawn = drawn_held(browser, f"axis-{name}", series)
            assert drawn["wrong"] == [], (name, series, drawn["wrong"][:5])
            assert drawn["checked"] >= 3, (name, series, drawn)
            telling, checked = telling + drawn["telling"], checked + drawn["checked"]
        # and where a straight line would have drawn motion that did not happen
        assert checked >= 20 and telling >= 1, (checked, telling)
        legend = browser.find_element(By.ID, "marks")
        assert "arrived" in legend.text and "DiscreteMotion" in legend.text
        browser.find_element(By.ID, "record").click()
        wait(browser, lambda d: d.find_element(By.ID, "report-link").get_attribute("data-id")
             == rec_id, "no report was downloaded")
        assert str(browser.find_element(By.ID, "report-link").get_attribute(
            "href")).startswith("blob:")
        rec = m.now(lambda: svc.session.recordings.get(rec_id).recording)
        offset = float(browser.execute_script("return state.clockOffset"))
        for name in ("x", "y", "r"):
            t, position, velocity, target = browser.execute_script(
                f"return DrivebusCharts.registry.get('axis-{name}').data()")
            samples = list(rec.axes[name].samples)  # type: ignore[attr-defined]
            times = [s.time for s in samples]
            matched = 0
            for i, x in enumerate(t):
                # the page plots poll time + (wall - monotonic): at 1.8e9 s a double
                # keeps ~0.3 µs, and polls are milliseconds apart
                when = x - offset
                if not rec.started <= when <= rec.stopped:  # type: ignore[attr-defined]
                    continue
                k = min(range(max(0, bisect.bisect_left(times, when) - 1),
                              min(len(times), bisect.bisect_left(times, when) + 1)),
                        key=lambda j: abs(times[j] - when))
                s = samples[k]
                assert abs(s.time - when) < 2e-6, f"{name}: plotted a point at {when} " \
                    f"no poll was at (nearest {s.time})"
                assert (position[i], velocity[i], target[i]) == (
                    s.position, s.velocity, s.target), (name, i)
                matched += 1
            assert matched >= 5, f"{name}: only {matched} plotted points in the recording"
        # the report the button fetched is the recording's, served by the service
        html = portal.call(lambda: client.get(f"/api/recordings/{rec_id}/report"))
        assert html.status_code == 200 and "DRIVEBUS_REPORT" in html.text
