"""What the browser tests share: Debian's headless Chromium through selenium and its
chromedriver, optionally with every request off this machine made to fail, and the
screenshots kept under ``tests/artifacts/`` (ignored by git)."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any
from urllib.parse import urlsplit

import pytest

from service_rig import ROOT

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

CHROMIUM = shutil.which("chromium")
CHROMEDRIVER = shutil.which("chromedriver")
ARTIFACTS = ROOT / "tests" / "artifacts"

needs_chromium = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="needs Debian's chromium and chromium-driver: `sh .ci/ensure-chromium` as root "
           "(make test runs it) or `apt-get install chromium chromium-driver`",
)

LOOPBACK = {"127.0.0.1", "localhost", "[::1]", "::1"}


@contextmanager
def chromium(*, offline: bool = False, height: int = 1100) -> Iterator[webdriver.Chrome]:
    """Headless Chromium with a fresh profile. ``offline``: the network is cut for
    everything but loopback (every request goes to a dead proxy, and no name resolves
    but localhost), and every request the page makes is logged (``requests_made``)."""
    assert CHROMIUM is not None and CHROMEDRIVER is not None
    with tempfile.TemporaryDirectory(prefix="drivebus-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for arg in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage", f"--user-data-dir={profile}",
                    f"--window-size=1280,{height}"):
            options.add_argument(arg)
        if offline:
            options.add_argument("--proxy-server=http://127.0.0.1:9")  # discard: nothing
            options.add_argument("--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, "
                                 "EXCLUDE 127.0.0.1")
            options.set_capability("goog:loggingPrefs", {"performance": "ALL"})
        driver = webdriver.Chrome(options=options,
                                  service=webdriver.ChromeService(executable_path=CHROMEDRIVER))
        try:
            yield driver
        finally:
            driver.quit()


def requests_made(driver: webdriver.Chrome) -> list[str]:
    """The URLs the page requested since the last call (an ``offline`` browser), less
    those its content security policy stopped inside the browser (they never left)."""
    urls: dict[str, str] = {}
    blocked: set[str] = set()
    for entry in driver.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        params = msg.get("params", {})
        if msg.get("method") == "Network.requestWillBeSent":
            urls[params["requestId"]] = params["request"]["url"]
        elif msg.get("method") == "Network.loadingFailed" and params.get(
                "blockedReason") == "csp":
            blocked.add(params["requestId"])
    return [url for rid, url in urls.items() if rid not in blocked]


def off_machine(urls: list[str]) -> list[str]:
    """The URLs among ``urls`` that would leave this machine."""
    out = []
    for url in urls:
        parts = urlsplit(url)
        if parts.scheme in ("data", "blob", "about", "file", "chrome", "chrome-untrusted",
                            "devtools"):
            continue
        if (parts.hostname or "") not in LOOPBACK:
            out.append(url)
    return out


def wait(driver: webdriver.Chrome, check: Callable[[webdriver.Chrome], object],
         message: str) -> None:
    """Wait for a condition on the page (a hang guard of 20 s, not a figure)."""
    WebDriverWait(driver, 20, poll_frequency=0.05).until(check, message)


def screenshot(driver: webdriver.Chrome, name: str) -> None:
    """Keep a screenshot of the page as ``tests/artifacts/NAME.png``."""
    ARTIFACTS.mkdir(exist_ok=True)
    shot = ARTIFACTS / f"{name}.png"
    assert driver.save_screenshot(str(shot))
    print(f"screenshot: {shot}")
    assert shot.stat().st_size > 10_000


_HELD = """
const [chartId, series] = arguments;
const u = DrivebusCharts.registry.get(chartId).u;
const path = u.series[series]._paths && u.series[series]._paths.stroke;
const t = u.data[0], y = u.data[series], scale = u.series[series].scale;
const ctx = u.ctx;
ctx.save();
ctx.setTransform(1, 0, 0, 1, 0, 0);
ctx.lineWidth = 2 * devicePixelRatio;
ctx.setLineDash([]);  // the context keeps the last series' dashes, and the probe honours them
const out = {checked: 0, telling: 0, wrong: []};
for (let i = 0; path && i + 1 < t.length; i++) {
  if (y[i] === null || y[i + 1] === null) continue;
  if (t[i] < u.scales.x.min || t[i + 1] > u.scales.x.max) continue;
  const x0 = u.valToPos(t[i], "x", true), x1 = u.valToPos(t[i + 1], "x", true);
  if (x1 - x0 < 6 * devicePixelRatio) continue;  // too close to tell a step from a line
  const xm = (x0 + x1) / 2;
  const held = u.valToPos(y[i], scale, true);
  const line = u.valToPos((y[i] + y[i + 1]) / 2, scale, true);
  out.checked += 1;
  if (!ctx.isPointInStroke(path, xm, held)) out.wrong.push([i, t[i], y[i], "not held"]);
  if (Math.abs(line - held) > 6 * devicePixelRatio) {
    out.telling += 1;
    if (ctx.isPointInStroke(path, xm, line)) out.wrong.push([i, t[i], y[i], "a line"]);
  }
}
ctx.restore();
return out;
"""


def drawn_held(driver: webdriver.Chrome, chart: str, series: int) -> dict[str, Any]:
    """How series ``series`` of chart ``chart`` is drawn between its samples, read from the
    path uPlot stroked (``isPointInStroke``): halfway between two samples far enough apart
    to tell, the line must be at the earlier sample's value (held), and not where a
    straight line between the two would be. ``checked``: the gaps looked at; ``telling``:
    those where a line would have been elsewhere; ``wrong``: ``[i, t, value, why]``."""
    out: dict[str, Any] = driver.execute_script(_HELD, chart, series)
    return out


def zoom(driver: webdriver.Chrome, chart: str, t0: float, t1: float) -> None:
    """Zoom chart ``chart`` in to the times ``t0``..``t1`` as a user does: a double-click
    to zoom out if the span is not all in view, then mouse drags across the plot from a
    few pixels before ``t0`` to a few after ``t1`` until it shows little more than that
    span (each drag zooms in; a pixel is then a smaller time)."""
    span = f"const x = DrivebusCharts.registry.get('{chart}').u.scales.x; return [x.min, x.max];"
    over, scrolled = driver.execute_script(f"""
        const over = DrivebusCharts.registry.get('{chart}').u.over, at = [scrollX, scrollY];
        over.scrollIntoView({{block: "center"}}); return [over, at];""")  # within the mouse's reach

    def shows(d: webdriver.Chrome) -> bool:
        lo, hi = d.execute_script(span)
        return bool(lo <= t0 and t1 <= hi)

    if not shows(driver):
        ActionChains(driver).double_click(over).perform()
        wait(driver, shows, f"{chart} did not zoom out to show {t0}..{t1}")
    # Up to eight drags (one or two do on a quiet machine): a busy browser may apply a drag
    # after the wait below saw the scale change for another reason (new samples).
    seen = []  # the spans shown before each drag (said when the drags fall short)
    for _ in range(8):
        lo, hi = driver.execute_script(span)
        seen.append(f"{lo - t0:+.4f}..{hi - t1:+.4f}")
        if hi - lo <= 2 * (t1 - t0):
            break
        x0, x1, width = driver.execute_script("""
            const u = DrivebusCharts.registry.get(arguments[0]).u;
            return [u.valToPos(arguments[1], "x"), u.valToPos(arguments[2], "x"),
                    u.over.getBoundingClientRect().width];""", chart, t0, t1)
        # three pixels to spare: the mouse moves in whole pixels from the plot's centre
        a, b = max(0, int(x0) - 3), min(int(width) - 1, int(x1) + 4)
        ActionChains(driver).move_to_element_with_offset(over, a - width // 2, 0) \
            .click_and_hold().move_by_offset(b - a, 0).release().perform()
        wait(driver, lambda d, was=(lo, hi): d.execute_script(span) != was,
             f"{chart} did not zoom in on a drag across {t0}..{t1}")
        assert shows(driver), f"{chart}: a drag across {t0}..{t1} showed {lo}..{hi}"
    lo, hi = driver.execute_script(span)
    assert hi - lo <= 2 * (t1 - t0), (
        f"{chart}: eight drags across {t0}..{t1} show {lo}..{hi} (before each drag, the "
        f"span from t0 and t1: {', '.join(seen)})")
    driver.execute_script("scrollTo(...arguments[0])", scrolled)
