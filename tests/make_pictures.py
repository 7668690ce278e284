"""The README's pictures (`make pictures`): the recording report of a group move on the
demo machine and the dashboard during one, taken in headless Chromium (as the browser
tests do) and written to docs/img/. Not a test: run it after changing the report or the
dashboard, look at the pictures, commit them."""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import anyio
from anyio.from_thread import start_blocking_portal

sys.path.insert(0, str(Path(__file__).resolve().parent))

from browser_rig import chromium, wait
from drivebus import open_machine
from drivebus.service.report import report_html
from service_rig import DEMO, ROOT, running, until

OUT = ROOT / "docs" / "img"
TARGETS = {"x": 150.0, "y": 60.0, "z": 40.0, "r": 270.0}


async def _report_page() -> str:
    async with open_machine(DEMO) as m, m.record(axes=["x", "y", "z", "r"]) as rec:
        await anyio.sleep(0.1)
        await m.group(*TARGETS).move_to(TARGETS)
        await m.axes["x"].move_to(40.0)
        await anyio.sleep(0.1)
    return report_html(rec)


def report() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "report.html"
        page.write_text(anyio.run(_report_page))
        with chromium(offline=True, height=1900) as browser:
            browser.get(page.as_uri())
            wait(browser, lambda d: d.execute_script("return document.body.dataset.ready"),
                 "the report did not build")
            browser.save_screenshot(str(OUT / "report.png"))


def dashboard() -> None:
    with (
        chromium(height=1250) as browser,
        start_blocking_portal() as portal,
        portal.wrap_async_context_manager(running()) as (svc, client),
    ):
        browser.get(f"{svc.url}/")
        wait(browser, lambda d: d.find_element("id", "conn").text == "live", "not live")
        browser.execute_script("document.getElementById('window').value = '10';"
                               "document.getElementById('window').dispatchEvent("
                               "new Event('change'))")
        portal.call(lambda: client.post("/api/machine/group-move", json={"targets": TARGETS}))
        twin = svc.session.machine.sim_drives["x"]
        portal.call(lambda: until(svc, lambda: twin.position() > 0.6 * 150 * 400,
                                  what="x did not get far"))
        time.sleep(0.4)  # two redraws
        browser.save_screenshot(str(OUT / "dashboard.png"))


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    report()
    dashboard()
    print(f"wrote {OUT / 'report.png'} and {OUT / 'dashboard.png'}")
