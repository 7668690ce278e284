"""The MQTT bridge's parts without a broker: command parsing, the outbox's bounds and
rates, the topic tree, options from a machine file's [mqtt] section."""

from __future__ import annotations

import tomllib

import anyio
import pytest

from drivebus.config import parse_broker_url, parse_config
from drivebus.errors import ArgumentError, ConfigError
from drivebus.mqtt import BridgeOptions, Topics, parse_command
from drivebus.mqtt.commands import peek_id
from drivebus.mqtt.discovery import discovery_messages
from drivebus.mqtt.outbox import Outbox, Outgoing
from mqtt_helpers import DEMO


def test_commands_parse_to_finite_numbers_or_name_the_problem() -> None:
    c = parse_command("x", "move", b'{"id": "a", "target": 10, "speed": 5.5}')
    assert (c.verb, c.axis, c.id, c.args) == ("move", "x", "a", {"target": 10.0, "speed": 5.5})
    assert parse_command("x", "stop", b"").args == {}
    assert parse_command("x", "jog", b'{"speed": -3}').args == {"speed": -3.0, "ttl": 1.0}
    for payload, problem in [
        (b"{", "not JSON"),
        (b'{"target": Infinity}', "Infinity is not a finite number"),
        (b'{"target": 1, "id": [1]}', "id: expected a string or a number"),
        (b'{"target": 1, "id": true}', "id: expected a string or a number"),
        (b'"x"', "expected a JSON object"),
        (b'{"target": null, "by": null}', "exactly one"),
        (b"[" * 100_000, "at most"),
        (b"[" * 5000, "nested too deeply"),
    ]:
        with pytest.raises(ArgumentError, match=problem):
            parse_command("x", "move", payload)
    assert peek_id(b'{"id": 4, "target": NaN}') == 4  # a bad command's id is still echoed
    assert peek_id(b"nope") is None


def test_topics_are_the_fixed_tree() -> None:
    t = Topics("cell1")
    assert t.status == "drivebus/cell1/status"
    assert t.state("x") == "drivebus/cell1/axes/x/state"
    assert t.command("x", "move") == "drivebus/cell1/axes/x/cmd/move"
    assert t.stats("rs485") == "drivebus/cell1/bus/rs485/stats"
    assert t.parse_command("drivebus/cell1/axes/x/cmd/jog") == ("x", "jog")
    assert t.parse_command("drivebus/cell2/axes/x/cmd/jog") is None
    assert t.is_estop("drivebus/estop") and t.is_estop("drivebus/cell1/estop")
    assert not t.is_estop("drivebus/cell2/estop")
    topics = {m.topic for m in discovery_messages(t, "demo", ["x"])}
    assert topics == {"homeassistant/sensor/drivebus_cell1/x_position/config",
                      "homeassistant/sensor/drivebus_cell1/x_state/config",
                      "homeassistant/button/drivebus_cell1/x_stop/config",
                      "homeassistant/button/drivebus_cell1/estop/config"}


async def test_the_outbox_is_latest_wins_rate_limited_and_bounded() -> None:
    box = Outbox(max_replies=3)
    for i in range(100):
        box.put(Outgoing("s/x", str(i).encode()), interval=3600.0)
    assert len(box) == 1
    assert (await box.get()).payload == b"99"
    box.put(Outgoing("s/x", b"100"), interval=3600.0)  # within its interval: it waits
    for i in range(10):
        box.reply(Outgoing("r", str(i).encode(), reply=True))
    assert box.dropped_replies == 7 and len(box) == 4
    assert [(await box.get()).payload for _ in range(3)] == [b"7", b"8", b"9"]  # replies first
    with anyio.move_on_after(0.05) as scope:
        await box.get()
    assert scope.cancelled_caught  # s/x is not due yet
    box.forget_rates()  # after a reconnection everything goes at once
    assert (await box.get()).payload == b"100"


def test_options_come_from_the_mqtt_section_and_the_command_line() -> None:
    data = tomllib.loads(DEMO.read_text())
    cfg = parse_config({**data, "mqtt": {"url": "mqtt://10.0.0.5", "node": "cellA",
                                         "state_rate": 4, "discovery": False}})
    o = BridgeOptions.resolve(cfg)
    assert (o.broker.host, o.broker.port, o.node, o.state_rate, o.discovery) == (
        "10.0.0.5", 1883, "cellA", 4.0, False)
    o = BridgeOptions.resolve(cfg, url="mqtt://127.0.0.1:1999", node="other", discovery=True)
    assert (str(o.broker), o.node, o.discovery) == ("mqtt://127.0.0.1:1999", "other", True)
    assert BridgeOptions.resolve(parse_config(data), url="mqtt://h").node == "demo"
    with pytest.raises(ConfigError, match="no MQTT broker"):
        BridgeOptions.resolve(parse_config(data))
    with pytest.raises(ConfigError, match="node name 'a/b'"):
        BridgeOptions.resolve(cfg, node="a/b")
    with pytest.raises(ConfigError, match="state_rate"):
        BridgeOptions(parse_broker_url("mqtt://h"), "n", state_rate=float("nan"))
    with pytest.raises(ConfigError, match=r"mqtt\.state_rate"):
        parse_config({**data, "mqtt": {"state_rate": float("inf")}})
    with pytest.raises(ConfigError, match=r"mqtt\.url.*scheme must be mqtt://"):
        parse_config({**data, "mqtt": {"url": "tcp://h:1"}})
    assert parse_broker_url("mqtt://u:p%40ss@h:1884").password == "p@ss"


def test_an_estop_taken_ahead_marks_the_commands_that_came_before_it() -> None:
    """The incoming queue serves an e-stop ahead of everything: the commands that arrived
    before it are marked overtaken when they are taken after it (the bridge drops them,
    as it drops those queued on the axes); one that arrived after it is not (an e-stop
    does not latch). They had run after the e-stop (an outside audit)."""
    import aiomqtt

    from drivebus.mqtt.bridge import _UrgentFirst

    def msg(topic: str) -> aiomqtt.Message:
        return aiomqtt.Message(topic, b"{}", 0, False, 0, None)

    async def main() -> list[tuple[str, bool]]:
        q = _UrgentFirst()
        for i in range(3):
            q.put_nowait(msg(f"drivebus/n/axes/z/cmd/move{i}"))
        q.put_nowait(msg("drivebus/n/estop"))
        taken = []
        for _ in range(2):
            m = await q.get()
            taken.append((m.topic.value, q.overtaken))
        q.put_nowait(msg("drivebus/n/axes/z/cmd/after"))
        while not q.empty():
            m = await q.get()
            taken.append((m.topic.value, q.overtaken))
        return taken

    assert anyio.run(main) == [
        ("drivebus/n/estop", False), ("drivebus/n/axes/z/cmd/move0", True),
        ("drivebus/n/axes/z/cmd/move1", True), ("drivebus/n/axes/z/cmd/move2", True),
        ("drivebus/n/axes/z/cmd/after", False)]
