"""``GET /metrics`` as Prometheus reads it: scraped from a real uvicorn server, parsed by
prometheus_client's parser, named by Prometheus's conventions (the unit in the name, a
base unit, quantiles only on a summary), positions as the twins have them, and behind a
token when the service has tokens."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from drivebus.service import TokenStore
from drivebus.service.metrics import base_unit
from service_rig import auth, running, token_file, until


def test_an_axis_unit_maps_to_a_base_unit() -> None:
    assert base_unit("mm", 10.0) == ("meters", 1e-3)
    assert base_unit("m", 1.0) == ("meters", 1.0)
    assert base_unit("µm", 1.0) == ("meters", 1e-6)
    assert base_unit("in", 1.0) == ("meters", 0.0254)
    assert base_unit("deg", 360.0) == ("radians", math.pi / 180)
    assert base_unit("rev", 1.0) == ("radians", 2 * math.pi)
    assert base_unit("units", 4.0) == ("revolutions", 0.25)  # the motor's revolutions
    assert base_unit("bottles", 2.0) == ("revolutions", 0.5)


async def test_metrics_follow_prometheus_naming_and_give_the_twins_positions() -> None:
    async with running() as (svc, client):
        bus, m = svc.session.machine.buses["rs485"], svc.session.machine
        await until(svc, lambda: bus.stats.slave(2).latency.count >= 5
                    and all(a.position is not None for a in m.axes.values()))
        r = await client.get("/metrics")
        assert r.status_code == 200
        families = list(text_string_to_metric_families(r.text))
        by_name = {f.name: f for f in families}
        for f in families:
            assert f.type in ("counter", "gauge", "histogram", "summary"), f.name
            for s in f.samples:
                # a quantile is a summary's label; a unit belongs in the name
                assert "quantile" not in s.labels or f.type == "summary", (f.name, s)
                assert "unit" not in s.labels, (f.name, s)
        assert "drivebus_axis_position" not in by_name

        def positions(name: str) -> dict[str, float]:
            return {s.labels["axis"]: s.value for s in by_name[name].samples}

        meters = positions("drivebus_axis_position_meters")
        radians = positions("drivebus_axis_position_radians")
        revolutions = positions("drivebus_axis_position_revolutions")
        assert set(meters) == {"x", "y", "z"} and set(radians) == {"r"}
        assert set(revolutions) == {"aux"}
        twins = m.sim_drives
        for name in ("x", "y", "z"):  # mm on the twins, metres in the metric
            units = m.axes[name].units
            assert meters[name] == pytest.approx(units.from_pulses(twins[name].position())
                                                 / 1000, abs=1e-9), name
        r_units = m.axes["r"].units
        assert radians["r"] == pytest.approx(math.radians(
            r_units.from_pulses(twins["r"].position())), abs=1e-9)
        aux = m.axes["aux"]
        assert aux.position is not None
        assert revolutions["aux"] == pytest.approx(aux.position / aux.config.units_per_rev)

        window = by_name["drivebus_reply_latency_window_seconds"]
        assert window.type == "summary"
        hist = by_name["drivebus_reply_latency_seconds"]
        two = {"line": "rs485", "slave": "2"}
        q = {s.labels["quantile"]: s.value for s in window.samples
             if s.labels.get("slave") == "2" and "quantile" in s.labels}
        assert set(q) == {"0.5", "0.99"} and 0 < q["0.5"] <= q["0.99"] < 1
        for suffix in ("_sum", "_count"):  # all replies, as the histogram counts them
            (mine,) = [s.value for s in window.samples
                       if s.name.endswith(suffix) and s.labels == two]
            (its,) = [s.value for s in hist.samples if s.name.endswith(suffix)
                      and s.labels == two]
            assert mine == its and mine > 0
        assert by_name["drivebus_transactions"].type == "counter"
        assert by_name["drivebus_line_utilisation_ratio"].type == "gauge"


async def test_metrics_need_a_token_when_the_service_has_tokens(tmp_path: Path) -> None:
    async with running(tokens=TokenStore.load(token_file(tmp_path))) as (_, client):
        r = await client.get("/metrics")
        assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Bearer")
        r = await client.get("/metrics", headers=auth("viewer"))  # a read token will do
        assert r.status_code == 200
        names = {f.name for f in text_string_to_metric_families(r.text)}
        assert "drivebus_axis_position_meters" in names
