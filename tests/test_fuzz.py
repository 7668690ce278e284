"""Issue 12: property-based fuzzing of everything a hostile peer or caller can feed drivebus.

* RTU replies from a peer on a real pty (the master is the real serial stack): random,
  truncated, corrupted, wrong-function, exception and oversized replies, and garbage
  around valid ones;
* Modbus TCP replies (MBAP) from a peer on a real loopback socket;
* machine files (mappings and TOML text) through the loader;
* the public Bus/SlaveHandle call arguments.

The property everywhere: the outcome is a correct result or a ``DrivebusError``, never
another exception type and never a hang; where a peer misbehaved, the line then works
again for a well-behaved reply. "Correct" is checked against the bytes the peer sent: a
read returns values only if a valid frame carrying exactly them was among those bytes.

Example counts are moderate and the runs derandomized, so the suite stays fast and its
outcome does not depend on luck; raise ``max_examples`` locally to hunt further.
"""

from __future__ import annotations

import asyncio
import math
import os
import struct
import tomllib
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from drivebus import Bus, Priority, TcpLine
from drivebus import pdu as P
from drivebus.config import load_config, parse_config
from drivebus.errors import ArgumentError, ConfigError, DrivebusError
from drivebus.line.rtu import frame
from drivebus.sim import RegisterSlave, sim_bus
from peers import FAST, UNIT, MakeReply, TcpPeer, mbap, pty_bus, values_pdu

HANG = 5.0
"""A call that takes longer than this (far above its timeouts) is a hang."""

_EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "150"))
"""Examples per property (FUZZ_EXAMPLES=N runs N, randomized, to hunt further)."""
FUZZ = settings(
    max_examples=_EXAMPLES,
    deadline=None,
    derandomize="FUZZ_EXAMPLES" not in os.environ,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
PER_KIND = settings(FUZZ, max_examples=max(1, _EXAMPLES // 6))
"""For properties run once per kind of misbehaviour (the kinds together get more)."""


# -- replies: what a hostile peer sends -----------------------------------------------------------

words = st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=8)


RTU_KINDS = ["valid", "random", "truncated", "corrupted", "wrong function", "exception",
             "oversized count", "trailing junk", "leading junk", "other unit",
             "unknown function"]


@st.composite
def replies(draw: st.DrawFn, kind: str, count: int) -> bytes:
    """The bytes a peer sends back, of ``kind``, for an FC03 read of ``count`` registers."""
    good = values_pdu(draw(st.lists(st.integers(0, 0xFFFF), min_size=count, max_size=count)))
    if kind == "valid":
        return frame(UNIT, good)
    if kind == "random":
        return draw(st.binary(min_size=0, max_size=300))
    if kind == "truncated":
        adu = frame(UNIT, good)
        return adu[: draw(st.integers(0, len(adu) - 1))]
    if kind == "corrupted":
        adu = bytearray(frame(UNIT, good))
        for _ in range(draw(st.integers(1, 3))):
            i = draw(st.integers(0, len(adu) - 1))
            adu[i] ^= draw(st.integers(1, 255))
        return bytes(adu)
    if kind == "wrong function":
        fc = draw(st.sampled_from([0x01, 0x02, 0x04, 0x06, 0x10, 0x17]))
        return frame(UNIT, bytes((fc,)) + good[1:])
    if kind == "exception":
        return frame(UNIT, bytes((0x83, draw(st.integers(0, 255)))))
    if kind == "oversized count":
        extra = draw(st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=127 - count))
        return frame(UNIT, values_pdu(list(struct.unpack(f">{count}H", good[2:])) + extra))
    if kind == "trailing junk":
        return frame(UNIT, good) + draw(st.binary(min_size=1, max_size=64))
    if kind == "leading junk":
        return draw(st.binary(min_size=1, max_size=64)) + frame(UNIT, good)
    if kind == "other unit":
        return frame(draw(st.integers(0, 255).filter(lambda u: u != UNIT)), good)
    fc = draw(st.integers(0x20, 0x7F))  # a function code whose reply length is unknown
    return frame(UNIT, bytes((fc,)) + draw(st.binary(max_size=20)))


def _frames_with(data: bytes, pdu: bytes, unit: int = UNIT) -> bool:
    """True if ``data`` contains the RTU frame of ``pdu`` from ``unit``."""
    return frame(unit, pdu) in data


@pytest.mark.parametrize("kind", RTU_KINDS)
@PER_KIND
@given(count=st.integers(1, 4), data=st.data())
def test_rtu_replies_give_a_correct_result_or_a_typed_error(
    kind: str, count: int, data: st.DataObject
) -> None:
    """Whatever comes back, the read returns the values of a valid frame that was sent, or
    raises a DrivebusError; and the next read, answered properly, works."""
    reply = data.draw(replies(kind, count), label="reply")
    good = [0x1234 + i for i in range(count)]

    async def run() -> None:
        async with pty_bus([reply, frame(UNIT, values_pdu(good))]) as bus:
            with anyio.fail_after(HANG):
                try:
                    values = await bus.slave(UNIT).read_holding_registers(0, count)
                except DrivebusError as exc:
                    event(f"failed: {type(exc).__name__}")
                else:
                    event("values")
                    assert len(values) == count
                    assert _frames_with(reply, values_pdu(values)), (reply.hex(" "), values)
                assert await bus.slave(UNIT).read_holding_registers(0, count) == good

    anyio.run(run)


@st.composite
def write_replies(draw: st.DrawFn, request: bytes) -> bytes:
    """The bytes a peer sends back for an FC06 ``request`` (unit 1)."""
    echo = frame(UNIT, request)
    kind = draw(st.sampled_from(["echo", "random", "truncated", "other value", "exception",
                                 "junk around"]))
    if kind == "echo":
        return echo
    if kind == "random":
        return draw(st.binary(max_size=40))
    if kind == "truncated":
        return echo[: draw(st.integers(0, len(echo) - 1))]
    if kind == "other value":
        return frame(UNIT, request[:3] + struct.pack(">H", (request[3] << 8 | request[4]) ^ 1))
    if kind == "exception":
        return frame(UNIT, bytes((0x86, draw(st.integers(1, 11)))))
    return draw(st.binary(max_size=16)) + echo + draw(st.binary(max_size=16))


@FUZZ
@given(value=st.integers(0, 0xFFFF), data=st.data())
def test_rtu_write_replies_confirm_only_an_exact_echo(value: int, data: st.DataObject) -> None:
    """An FC06 write succeeds only if the peer's bytes contain the exact echo of its request."""
    request = P.write_single_request(7, value)
    sent = data.draw(write_replies(request), label="reply")

    async def run() -> None:
        async with pty_bus([sent]) as bus:
            with anyio.fail_after(HANG):
                try:
                    await bus.slave(UNIT).write_register(7, value)
                except DrivebusError:
                    return
                assert frame(UNIT, request) in sent, sent.hex(" ")

    anyio.run(run)


# -- a Modbus TCP peer on a loopback socket ------------------------------------------------------

TCP_KINDS = ["valid", "random", "truncated", "wrong tid", "wrong protocol", "bad length",
             "wrong unit", "wrong function", "byte count mismatch", "exception",
             "trailing junk", "twice", "header only"]


@st.composite
def tcp_replies(draw: st.DrawFn, kind: str, count: int) -> MakeReply:
    """How a Modbus TCP peer answers, with ``kind``, an FC03 read of ``count`` registers."""
    good = values_pdu(draw(st.lists(st.integers(0, 0xFFFF), min_size=count, max_size=count)))
    junk = draw(st.binary(min_size=1, max_size=40))
    n = draw(st.integers(0, 0xFFFF))
    cut = draw(st.integers(0, 6 + len(good)))
    if kind == "valid":
        return lambda tid: mbap(tid, good)
    if kind == "random":
        return lambda tid: junk
    if kind == "truncated":
        return lambda tid: mbap(tid, good)[:cut]
    if kind == "wrong tid":
        return lambda tid: mbap(tid ^ (n or 1), good)
    if kind == "wrong protocol":
        return lambda tid: mbap(tid, good, protocol=n or 1)
    if kind == "bad length":
        return lambda tid: mbap(tid, good, length=n) + junk
    if kind == "wrong unit":
        other = (UNIT + 1 + n) % 256 if (UNIT + 1 + n) % 256 != UNIT else 0
        return lambda tid: mbap(tid, good, unit=other)
    if kind == "wrong function":
        return lambda tid: mbap(tid, bytes((0x04,)) + good[1:])
    if kind == "byte count mismatch":
        return lambda tid: mbap(tid, bytes((good[0], (good[1] + 2) & 0xFF)) + good[2:])
    if kind == "exception":
        return lambda tid: mbap(tid, bytes((0x83, n & 0xFF)))
    if kind == "trailing junk":
        return lambda tid: mbap(tid, good) + junk
    if kind == "twice":
        return lambda tid: mbap(tid, good) * 2
    return lambda tid: mbap(tid, good)[:7]


@pytest.mark.parametrize("kind", TCP_KINDS)
@PER_KIND
@given(count=st.integers(1, 4), data=st.data())
def test_tcp_replies_give_a_correct_result_or_a_typed_error(
    kind: str, count: int, data: st.DataObject
) -> None:
    """Whatever a Modbus TCP peer sends, the read returns the values of a well-formed reply
    to it, or raises a DrivebusError; then the line works again (reconnecting if the
    stream was out of step)."""
    make = data.draw(tcp_replies(kind, count), label="reply")
    good = [0x4321 + i for i in range(count)]

    async def run() -> None:
        peer = TcpPeer(make, good)
        server = await asyncio.start_server(peer.serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        try:
            line = TcpLine("127.0.0.1", port, reconnect_delay=0.0)
            async with Bus(line, timeout=0.05, retries=0) as bus:
                with anyio.fail_after(HANG):
                    try:
                        values = await bus.slave(UNIT).read_holding_registers(0, count)
                    except DrivebusError as exc:
                        event(f"failed: {type(exc).__name__}")
                    else:
                        event("values")
                        assert len(values) == count
                        reply = mbap(peer.tids[0], values_pdu(values))
                        assert reply in peer.sent[0], peer.sent
                    again = bus.slave(UNIT, retries=3)
                    assert await again.read_holding_registers(0, count) == good, peer.sent
        finally:
            server.close()
            await server.wait_closed()

    anyio.run(run)


# -- machine files ---------------------------------------------------------------------------------

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"

hostile_values = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(),
    st.sampled_from([math.nan, math.inf, -math.inf, 0, -1, 0.0, -0.0, 1e308, 5e-324]),
    st.text(max_size=12), st.sampled_from(["9600 8N1", "12345 8E1", "sim://demo-rs485", "nan"]),
    st.lists(st.floats(), max_size=3), st.dictionaries(st.text(max_size=6), st.integers(),
                                                       max_size=2),
)


@st.composite
def mutated_demo(draw: st.DrawFn) -> dict[str, Any]:
    """The demo machine with a few keys set to hostile values, removed or added."""
    data = tomllib.loads(DEMO.read_text())
    for _ in range(draw(st.integers(1, 4))):
        node: Any = data
        while isinstance(node, dict) and node and draw(st.booleans()):
            key = draw(st.sampled_from(sorted(node)))
            if not isinstance(node[key], dict):
                break
            node = node[key]
        if not isinstance(node, dict):
            continue
        action = draw(st.sampled_from(["set", "delete", "add"]))
        if action == "add" or not node:
            node[draw(st.text(min_size=1, max_size=8))] = draw(hostile_values)
        elif action == "delete":
            del node[draw(st.sampled_from(sorted(node)))]
        else:
            node[draw(st.sampled_from(sorted(node)))] = draw(hostile_values)
    return data


@FUZZ
@given(mutated_demo())
def test_machine_file_mappings_load_or_give_one_config_error(data: dict[str, Any]) -> None:
    try:
        cfg = parse_config(data, "fuzz.toml")
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.toml: ")
        return
    for ax in cfg.axes.values():  # what was accepted is usable: finite, in its line
        assert math.isfinite(ax.units_per_rev) and ax.units_per_rev != 0
        assert ax.line in cfg.lines


toml_text = st.one_of(
    st.text(max_size=200),
    st.builds(lambda a, b: a + b, st.just(DEMO.read_text()), st.text(max_size=40)),
    st.builds(lambda t, i, junk: t[:i] + junk + t[i:], st.just(DEMO.read_text()),
              st.integers(0, len(DEMO.read_text())), st.text(max_size=20)),
)


@FUZZ
@given(text=toml_text, raw=st.binary(max_size=40))
def test_machine_file_text_loads_or_gives_one_config_error(
    text: str, raw: bytes, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """Any file content (text, or bytes that are not UTF-8) loads or is one ConfigError."""
    f = tmp_path_factory.mktemp("fuzz") / "m.toml"
    for content in (text.encode("utf-8", "surrogatepass"), raw):
        f.write_bytes(content)
        try:
            load_config(f)
        except ConfigError as exc:
            assert str(exc).startswith(str(f)), str(exc)


# -- public call arguments -----------------------------------------------------------------------

anything = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**40), 2**40), st.floats(), st.text(max_size=4),
    st.binary(max_size=4), st.lists(st.integers(-2, 70000), max_size=3),
    st.sampled_from([math.nan, math.inf, -1, 1.5, 2.0, 65535, 65536, Priority.EMERGENCY]),
)


def mostly(valid: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    """``valid`` three times in four, else anything at all."""
    return st.integers(0, 3).flatmap(lambda i: anything if i == 0 else valid)


address = mostly(st.integers(0, 1100))
count = mostly(st.integers(0, 130))
word = mostly(st.integers(0, 0xFFFF))
priority = mostly(st.sampled_from(list(Priority)))


@st.composite
def calls(draw: st.DrawFn) -> tuple[str, tuple[Any, ...], dict[str, Any]]:
    """A public SlaveHandle call with arguments from anywhere: name, args, keyword args."""
    name = draw(st.sampled_from(["read_holding_registers", "read_input_registers",
                                 "write_register", "write_registers", "transact"]))
    kw = {"priority": draw(priority)} if draw(st.booleans()) else {}
    if name.startswith("read"):
        return name, (draw(address), draw(count)), kw
    if name == "write_register":
        return name, (draw(address), draw(word)), kw
    if name == "write_registers":
        values = draw(mostly(st.lists(word, max_size=5)
                             | st.lists(st.integers(0, 9), min_size=120, max_size=130)))
        return name, (draw(address), values), kw
    return name, (draw(st.binary(max_size=8) | anything),), kw


@FUZZ
@given(call=calls(), slave_args=st.fixed_dictionaries({}, optional={
    "address": mostly(st.sampled_from([1, 0, 2, 247])), "timeout": mostly(st.floats(0.05, 0.2)),
    "retries": mostly(st.integers(0, 2))}))
def test_public_call_arguments_give_a_correct_result_or_a_typed_error(
    call: tuple[str, tuple[Any, ...], dict[str, Any]], slave_args: dict[str, Any]
) -> None:
    """``bus.slave(...)`` and the register calls with arguments of any type and value: a
    correct result (checked against the simulated slave) or a DrivebusError (ArgumentError
    or ConfigError if the arguments are at fault, then with nothing sent)."""
    name, args, kw = call
    slave = RegisterSlave(1, FAST, initial=[(i, 1000 + i) for i in range(1024)])

    async def run() -> None:
        async with sim_bus([slave], FAST, timeout=0.05, retries=0) as (wire, bus):
            try:
                handle = bus.slave(**{"address": 1, **slave_args})
                # a hang: longer than every attempt's timeout (a silent address takes that)
                with anyio.fail_after(handle.timeout * (handle.retries + 1) + HANG):
                    result = await getattr(handle, name)(*args, **kw)
            except (ArgumentError, ConfigError) as exc:
                event(f"refused: {type(exc).__name__}")
                assert wire.request_count == 0
                return
            except DrivebusError as exc:
                event(f"failed: {type(exc).__name__}")
                return
            event(f"done: {name}")
            a = handle.address
            if a != 1:  # another address or broadcast: nobody there, or nobody answers
                assert a == 0 and name.startswith("write")
                return
            start = int(args[0]) if name != "transact" else 0
            if name.startswith("read"):
                assert result == slave.registers[start : start + int(args[1])]
            elif name.startswith("write"):  # once, or again after a lost reply (idempotent)
                written = [int(args[1])] if name == "write_register" else list(map(int, args[1]))
                assert slave.writes and set(map(str, slave.writes)) == {str((start, written))}
                assert slave.registers[start : start + len(written)] == written
            else:
                assert isinstance(result, bytes) and result

    anyio.run(run)
