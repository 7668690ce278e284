"""The recording report and the API docs in headless Chromium with the network cut:
everything they need comes from the file or the package, and the report plots exactly
the recording (read back through the page's charts). Screenshots go to tests/artifacts/."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest
from anyio.from_thread import start_blocking_portal

from browser_rig import (
    chromium,
    drawn_held,
    needs_chromium,
    off_machine,
    requests_made,
    screenshot,
    wait,
)
from drivebus.service.report import report_data, report_html
from service_rig import running
from test_recording import recorded_group_move

pytestmark = needs_chromium

By = pytest.importorskip("selenium.webdriver.common.by").By


def test_the_report_of_a_group_move_plots_the_recording(tmp_path: Path) -> None:
    rec = anyio.run(recorded_group_move, "rec-report")  # the browser after, with no loop
    path = tmp_path / "group-move.html"
    path.write_text(report_html(rec))
    want = report_data(rec)
    telling = {1: 0, 2: 0, 3: 0}
    with chromium(offline=True, height=1500) as browser:
        browser.get(path.as_uri())
        wait(browser, lambda d: d.execute_script("return document.body.dataset.ready"),
             "the report did not build its charts")
        for a in want["axes"]:
            data = browser.execute_script(
                f"return DrivebusCharts.registry.get('axis-{a['name']}').data()")
            assert data == [a["t"], a["position"], a["velocity"], a["target"]]
            assert [s.position for s in rec.axes[a["name"]].samples] == a["position"]
            marks = browser.execute_script(
                f"return DrivebusCharts.registry.get('axis-{a['name']}').extra.marks")
            kinds = [m["kind"] for m in marks]
            assert "planned" in kinds and "in_position" in kinds
            for series in (1, 2, 3):  # position, velocity, target: each poll held
                drawn = drawn_held(browser, f"axis-{a['name']}", series)
                assert drawn["wrong"] == [], (a["name"], series, drawn["wrong"][:5])
                assert drawn["checked"] >= 5, (a["name"], series, drawn)
                telling[series] += drawn["telling"]
        for ln in want["lines"]:
            data = browser.execute_script(
                f"return DrivebusCharts.registry.get('line-{ln['name']}').data()")
            assert data == [ln["t"], ln["utilisation"], ln["rate"], ln["latency"]]
        # where a straight line between two polls would have drawn motion that did not
        # happen (a drift, a ramp), the chart holds the earlier poll
        assert telling[1] >= 1 and telling[2] >= 5, telling
        legend = browser.find_element(By.ID, "marks")
        kinds = {e.get_attribute("data-kind") for e in legend.find_elements(
            By.CSS_SELECTOR, "span[data-kind]")}
        assert {"started", "in_position", "planned", "stop"} <= kinds
        states = {e.get_attribute("data-state") for e in legend.find_elements(
            By.CSS_SELECTOR, "span[data-state]")}
        assert {"Standstill", "DiscreteMotion", "Stopping"} <= states
        assert "state" in legend.text and "planned arrival" in legend.text
        rows = browser.find_elements(By.CSS_SELECTOR, "#arrivals tbody tr")
        assert len(rows) == len(rec.arrivals()) == 4  # x, y, r together, then x alone
        assert off_machine(requests_made(browser)) == []
        screenshot(browser, "report-group-move")


def test_the_api_docs_load_with_the_network_cut() -> None:
    with (
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running()) as (svc, _),
        chromium(offline=True) as browser,
    ):
        browser.get(f"{svc.url}/docs")
        wait(browser, lambda d: d.find_elements(By.CSS_SELECTOR, ".swagger-ui .info .title"),
             "Swagger UI did not render")
        wait(browser, lambda d: d.find_elements(By.CSS_SELECTOR, ".opblock-tag"),
             "Swagger UI did not list the routes")
        assert "drivebus: machine demo" in browser.find_element(
            By.CSS_SELECTOR, ".swagger-ui .info .title").text
        screenshot(browser, "docs-offline")
        assert off_machine(requests_made(browser)) == []

        browser.get(f"{svc.url}/redoc")
        wait(browser, lambda d: "drivebus: machine demo" in d.find_element(
            By.TAG_NAME, "body").text and d.find_elements(By.CSS_SELECTOR, "h1"),
            "ReDoc did not render")
        screenshot(browser, "redoc-offline")
        assert off_machine(requests_made(browser)) == []
