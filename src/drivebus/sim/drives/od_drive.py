"""SimODDrive: the simulated twin of the OD2000 object-dictionary drive.

It speaks the drive's non-standard frames (a sub-index byte after the 16-bit index, 9-byte
FC03/FC06 requests, FC10 with the sub byte), answers with the drive's own exception codes
(01 CRC, 02 function code, 03 address, 04 read count > 16, 05 access, 06 range) and keeps
the object dictionary of the manual, with its own copy of the table so that a profile
table error shows up in tests.

Choices where the manual is silent or contradicts itself (each is a twin option or noted):

* CRC errors: the text says "discard, no reply", the CRC-valid example replies
  ``01 83 01 80 F0``. The twin follows the example (``crc_error_reply=True``, via
  ``on_bad_crc``); ``crc_error_reply=False`` gives the silent behaviour.
* A multi-register read or write walks the dictionary's entries in order (2002h.0 is
  followed by 2003h.1). That is the only reading under which the manual's example reply
  ``01 03 08 00 01 00 02 00 00 01 F4`` to a 4-register read from 2000h.0 is possible
  (there is no 2003h.0); configure ``objects={(0x2001, 0): 2, (0x2003, 1): 500}`` for it.
* The drive cannot move the motor by itself: its motion comes from the fieldbus master.
  ``external_move_to``/``external_run``/``external_stop`` stand in for that master.
  The accumulated command position 2010h/2011h is the simulated motor position; 2017h
  "speed reference" reports |speed| in r/min (unit not stated in the manual).
* 201Fh "motor does not move" code carries the latched alarm (``raise_alarm(code)``);
  201Eh = 1 clears it, and the fault list 201Ch keeps it until 201Dh = 1.
* A power cycle reloads the saved ("S") values, resets the others to their defaults,
  clears the alarm and the position counter.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

from drivebus.clock import monotonic
from drivebus.settings import LineSettings
from drivebus.sim.drive import SimDrive, TwinSetup, time_or_present
from drivebus.sim.registers import Access, ExceptionCodes, RegisterSpec, SlaveException

__all__ = ["SimODDrive"]

_DEFAULT_SETTINGS = LineSettings.parse("9600 8N1")

# Exception codes of the drive (table L466-492): 01 CRC error, 02 function code, 03 address,
# 04 read count > 16, 05 access, 06 range.
_EXCEPTION_CODES = ExceptionCodes(function=2, address=3, access=5, value=6, count=4, crc=1)


def _object(
    default: int, minimum: int, maximum: int, access: Access = Access.RW, *, saved: bool = True
) -> RegisterSpec:
    """An object of the dictionary; most are saved ("S": kept by a save, reloaded at power-on)."""
    return RegisterSpec(default, minimum, maximum, access, stored=saved)


# The manual's table (L26-321), in dictionary order. Defaults as printed, even where they
# lie outside the printed range (2005h: 1000 vs 6400~51200; 200Bh: 0 vs 10~3000).
_TABLE: dict[tuple[int, int], RegisterSpec] = {
    (0x2000, 0): _object(1, 0, 65535),
    (0x2001, 0): _object(0, 0, 2),  # printed 0~1, but value 2 (ESC EEPROM) is documented
    (0x2002, 0): _object(0, 0, 1),
    (0x2003, 1): _object(50, 10, 3000),
    (0x2003, 2): _object(50, 0, 100),
    (0x2004, 0): _object(1000, 100, 7000),
    (0x2005, 0): _object(1000, 6400, 51200),
    (0x2006, 0): _object(0, 0, 1),
    (0x2007, 0): _object(1, 0, 1),
    (0x2008, 0): _object(300, 50, 32767),
    (0x2009, 0): _object(30, 10, 2000),
    (0x200A, 0): _object(75, 0, 32767, Access.R),
    (0x200B, 0): _object(0, 10, 3000),
    (0x200C, 0): _object(0, 0, 1),
    (0x200D, 0): _object(0, 0, 65535, Access.R, saved=False),
    (0x200E, 0): _object(0, 0, 1),
    (0x200F, 0): _object(0, 0, 360),
    (0x2010, 0): _object(0, 0, 65535, Access.R, saved=False),
    (0x2011, 0): _object(0, 0, 65535, saved=False),
    (0x2012, 0): _object(1600, 0, 3000, saved=False),
    (0x2013, 0): _object(0, 0, 1),
    (0x2014, 0): _object(0, 0, 65535, Access.R, saved=False),
    (0x2015, 0): _object(0, 0, 1),
    (0x2016, 0): _object(1000, 50, 25600),
    (0x2017, 0): _object(0, 0, 32767, Access.R, saved=False),
    (0x2018, 0): RegisterSpec(1000, -32768, 32767, signed=True, stored=True),
    (0x2019, 0): _object(0, 0, 1),
    (0x201A, 1): _object(1, 0, 32767, Access.R, saved=False),
    (0x201A, 2): _object(0, 0, 32767, Access.R, saved=False),
    (0x201A, 3): _object(1, 0, 32767, Access.R, saved=False),
    (0x201B, 0): _object(0xC3, 0, 65535),
    **{(0x201C, n): _object(0, 0, 65535) for n in range(1, 10)},
    (0x201D, 0): _object(0, 0, 1, saved=False),
    (0x201E, 0): _object(0, 0, 1, saved=False),
    (0x201F, 0): _object(0, 0, 32767, Access.R, saved=False),
    (0x2020, 0): _object(0, 0, 32767),
    (0x2021, 0): _object(0, 0, 0x1F),  # bitmask of 5 inputs, printed range 0~1
    **{
        (0x2022, n): _object(d, 0, 255)
        for n, d in zip(range(1, 6), (32, 1, 2, 4, 16), strict=True)
    },
    **{(0x2023, n): _object(1000, 50, 60000) for n in range(1, 6)},
    (0x2024, 0): _object(0, 0, 0x07),  # bitmask of 3 outputs, printed range 0~1
    **{(0x2025, n): _object(d, 0, 255) for n, d in zip(range(1, 4), (1, 1, 4), strict=True)},
    (0x2030, 0): _object(0, 0, 255, Access.W),
}
_ORDER: list[tuple[int, int]] = sorted(_TABLE)
_POSITION = {key: i for i, key in enumerate(_ORDER)}
_AUTO_TUNED_GAINS = ((0x2008, 0), (0x2009, 0))  # read-only while auto-tune 2007h is on


class SimODDrive(SimDrive):
    """The OD2000 twin: object dictionary, non-standard frames, vendor exceptions, alarms."""

    family = "OD2000"
    exception_codes = _EXCEPTION_CODES
    max_read = 16

    def __init__(
        self,
        address: int = 1,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        crc_error_reply: bool = True,
        objects: Mapping[tuple[int, int], int] | None = None,
        bus_voltage: int = 48,
    ) -> None:
        if address != 1:
            raise ValueError(f"the OD2000 drive's serial address is fixed at 1, not {address}")
        super().__init__(address, settings or _DEFAULT_SETTINGS, setup)
        self.crc_error_reply = crc_error_reply
        """Answer a damaged frame with exception 01 (the manual's example) or stay silent."""
        self.bus_voltage = bus_voltage
        self.values: dict[tuple[int, int], int] = {k: e.default for k, e in _TABLE.items()}
        for key, value in (objects or {}).items():
            if key not in _TABLE:
                raise ValueError(f"the OD2000 drive has no object {key[0]:04X}h.{key[1]}")
            self.values[key] = value
        self.saved: dict[tuple[int, int], int] = self._persistent()
        """What a save (2030h bit0) stored; reloaded at power-on."""
        self.saves = 0
        self._damaged = 0

    # -- test hooks --------------------------------------------------------------------------

    def damage_requests(self, times: int = 1) -> None:
        """The next ``times`` requests arrive damaged (line noise): CRC-error handling."""
        self._damaged += times

    @property
    def pulses_per_rev(self) -> int:
        """The microstep setting 2005h."""
        return self.values[(0x2005, 0)]

    def external_move_to(
        self, target: int, speed_rpm: float, accel_rps2: float, now: float | None = None
    ) -> None:
        """The fieldbus master commands a move to ``target`` pulses (refused while alarmed)."""
        self._check_no_alarm()
        ramp = self.pulse_acceleration(accel_rps2)
        self.kin.move_to(time_or_present(now), target, self.pulse_rate(speed_rpm), ramp, ramp)

    def external_run(
        self, speed_rpm: float, accel_rps2: float, now: float | None = None
    ) -> None:
        """The fieldbus master runs the motor at ``speed_rpm`` (signed; refused while alarmed)."""
        self._check_no_alarm()
        ramp = self.pulse_acceleration(accel_rps2)
        self.kin.run(time_or_present(now), self.pulse_rate(speed_rpm), ramp, ramp)

    def _check_no_alarm(self) -> None:
        """The drive does not move the motor while an alarm is latched."""
        if self.alarm_code:
            raise RuntimeError(f"OD2000 twin: alarm {self.alarm_code} is latched")

    def external_stop(self, decel_rps2: float | None = None, now: float | None = None) -> None:
        """The fieldbus master stops the motor (None: at once)."""
        t = time_or_present(now)
        self.kin.stop(t, None if decel_rps2 is None else self.pulse_acceleration(decel_rps2))

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm ``code``: the motor stops, 201Fh reports it, 201Ch.1 records it."""
        super().raise_alarm(code, now)
        history = [self.values[(0x201C, n)] for n in range(1, 10)]
        for n, value in enumerate([code, *history[:8]], start=1):
            self.values[(0x201C, n)] = value

    def power_restore(self) -> None:
        """Power-on: saved values come back, the rest default; alarm and counter cleared."""
        super().power_restore()
        self.values = {k: e.default for k, e in _TABLE.items()}
        self.values.update(self.saved)
        self.alarm_code = 0
        self.kin.hold(monotonic(), 0)

    def _persistent(self) -> dict[tuple[int, int], int]:
        return {k: v for k, v in self.values.items() if _TABLE[k].stored}

    # -- frames --------------------------------------------------------------------------------

    def request_length(self, pdu: bytes) -> int | None:
        """PDU length of the drive's requests: 6 for FC03/FC06 (and unknown codes, as in the
        manual's FC02 example), 7 + byte count for FC10."""
        if not pdu:
            return None
        if pdu[0] == 0x10:
            return 7 + pdu[6] if len(pdu) >= 7 else None
        return 6

    def handle_pdu(self, pdu: bytes, now: float) -> bytes | None:
        """Answer one request PDU, or a request damaged on the way as a bad CRC."""
        if self._damaged > 0:
            self._damaged -= 1
            return self.on_bad_crc(bytes((self.address,)) + pdu)
        return super().handle_pdu(pdu, now)

    def answer(self, pdu: bytes, now: float) -> bytes:
        """The reply to an FC03/FC06/FC10 request in the drive's framing."""
        function = pdu[0]
        if function == 0x03:
            return self._read(pdu, now)
        if function == 0x06:
            return self._write_single(pdu, now)
        if function == 0x10:
            return self._write_multiple(pdu, now)
        raise SlaveException(self.exception_codes.function)

    @staticmethod
    def _walk(index: int, sub: int, count: int) -> list[tuple[int, int]]:
        start = _POSITION.get((index, sub))
        if start is None or start + count > len(_ORDER):
            raise SlaveException(_EXCEPTION_CODES.address)
        return _ORDER[start : start + count]

    def _read(self, pdu: bytes, now: float) -> bytes:
        if len(pdu) != 6:
            raise SlaveException(self.exception_codes.address)
        index, sub, count = struct.unpack_from(">HBH", pdu, 1)
        self.check_count(count)
        keys = self._walk(index, sub, count)
        for key in keys:
            _TABLE[key].check_read(self.exception_codes)
        words = [self._value(k, now) & 0xFFFF for k in keys]
        return bytes((0x03, 2 * count)) + struct.pack(f">{count}H", *words)

    def _write_single(self, pdu: bytes, now: float) -> bytes:
        if len(pdu) != 6:
            raise SlaveException(self.exception_codes.address)
        index, sub, word = struct.unpack_from(">HBH", pdu, 1)
        key = self._walk(index, sub, 1)[0]
        value = self._check_write(key, word)
        self._apply(key, value, now)
        return pdu

    def _write_multiple(self, pdu: bytes, now: float) -> bytes:
        index, sub, count = struct.unpack_from(">HBH", pdu, 1)
        self.check_count(count)
        if pdu[6] != 2 * count or len(pdu) != 7 + 2 * count:
            raise SlaveException(self.exception_codes.address)
        keys = self._walk(index, sub, count)
        words = struct.unpack_from(f">{count}H", pdu, 7)
        values = [self._check_write(k, w) for k, w in zip(keys, words, strict=True)]
        for k, v in zip(keys, values, strict=True):  # all checked first: all or nothing
            self._apply(k, v, now)
        return pdu[:6]

    # -- the dictionary ------------------------------------------------------------------------

    def _check_write(self, key: tuple[int, int], word: int) -> int:
        """The value a write of ``word`` to ``key`` sets (access, auto-tune lock, range)."""
        if key in _AUTO_TUNED_GAINS and self.values[(0x2007, 0)] == 1:
            raise SlaveException(self.exception_codes.access)
        return _TABLE[key].check_write(word, self.exception_codes)

    def _value(self, key: tuple[int, int], now: float) -> int:
        index = key[0]
        if index in (0x2010, 0x2011):
            counter = self.position(now) & 0xFFFFFFFF
            return counter >> 16 if index == 0x2010 else counter & 0xFFFF
        if index == 0x2014:
            return self._inputs(now)
        if index == 0x2017:
            rpm = abs(self.speed_rpm(now))
            return min(max(1, round(rpm)), 32767) if rpm > 0 else 0
        if index == 0x200D:
            return self.bus_voltage
        if index == 0x201F:
            return self.alarm_code
        return self.values[key]

    def _inputs(self, now: float) -> int:
        """2014h: bit n-1 set while input n's function (2022h.n) sees its switch."""
        home, neg, pos = self.switch_states(now)
        bits = 0
        for n in range(1, 6):
            function = self.values[(0x2022, n)]
            if (function & 1 and home) or (function & 2 and pos) or (function & 4 and neg):
                bits |= 1 << (n - 1)
        return bits

    def _apply(self, key: tuple[int, int], value: int, now: float) -> None:
        index = key[0]
        if index == 0x2011:
            if value == 1:  # "Writing 1 clears the counter"
                self.kin.set_position(now, 0)
            return
        if index == 0x201D:
            if value == 1:
                for n in range(1, 10):
                    self.values[(0x201C, n)] = 0
            return
        if index == 0x201E:
            if value == 1:
                self.alarm_code = 0
            return
        if index == 0x2030:
            if value & 0x02:
                self.values = {k: e.default for k, e in _TABLE.items()}
            if value & 0x01:
                self.saved = self._persistent()
                self.saves += 1
            return
        self.values[key] = value
