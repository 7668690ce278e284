"""``DescribedCia402Drive``: the twin of a CiA 402 description, its objects played by the
simulated CiA 402 device (``drivebus.sim.cia402_device``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar

from drivebus.clock import monotonic
from drivebus.drives.cia402 import OBJECTS, State
from drivebus.drives.description import Description, Reg, object_name
from drivebus.drives.units import Kind
from drivebus.settings import LineSettings
from drivebus.sim.cia402_device import Cia402Device, Cia402Setup
from drivebus.sim.described.drive import DescribedDrive
from drivebus.sim.drive import HomeCam, SimDrive, TwinSetup, time_or_present
from drivebus.sim.registers import signed32


class DescribedCia402Drive(DescribedDrive):
    """A twin of a CiA 402 description: the registers mapped to CiA 402 objects are the
    simulated device's (``Cia402Device``: state machine, profile position and velocity,
    homing, on this twin's kinematics); the others are plain registers as in any twin."""

    _objects: ClassVar[dict[str, Reg]]

    @classmethod
    def twin_options(cls) -> list[str]:
        """The keyword options this twin takes (``home_cam``: the side the home switch
        is active on, its device's; without it, the side the method in 6098h expects)."""
        return [o for o in super().twin_options() if o != "soft_address"]

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        home_switch_width: float | None = None,
        home_cam: HomeCam | None = None,
        crc_error_reply: bool = True,
        **constants: int,
    ) -> None:
        super().__init__(address, settings, setup, home_switch_width=home_switch_width,
                         home_cam=home_cam, crc_error_reply=crc_error_reply, **constants)
        d = self.description
        s = setup or TwinSetup()
        ppr = self.pulses_per_rev
        methods = frozenset(m.cia402 for m in (d.homing.methods.values() if d.homing else [])
                            if m.cia402 is not None) or None
        self.device = Cia402Device(
            Cia402Setup(
                position=s.position, home_switch=s.home_switch,
                home_switch_width=home_switch_width, home_cam=home_cam,
                limit_negative=s.limit_negative,
                limit_positive=s.limit_positive, increments_per_rev=ppr,
                velocity_unit=_pulses_per_raw(d, "velocity", ppr),
                acceleration_unit=_pulses_per_raw(d, "acceleration", ppr),
                **({"homing_methods": methods} if methods else {}),
            ),
            defaults={name: reg.default_at(None) for name, reg in self._objects.items()
                      if reg.d.default and OBJECTS[name].writable},
            codes=self.exception_codes, kin=self.kin, now=0.0,
        )

    def set_home_shape(self, home_cam: str | None, home_switch_width: float | None) -> None:
        """The home switch's shape, the device's too (a cam on ``home_cam``'s side, by
        default the side the homing method expects, or a dog of ``home_switch_width``)."""
        super().set_home_shape(home_cam, home_switch_width)
        device = getattr(self, "device", None)
        if device is not None:
            device.setup = replace(device.setup, home_cam=self.home_cam,
                                   home_switch_width=self.home_switch_width)

    # -- the device's state as a twin shows it ------------------------------------------------

    @property  # type: ignore[override]
    def enabled(self) -> bool:
        """Operation enabled."""
        device = getattr(self, "device", None)
        return device is not None and device.state_at() is State.OPERATION_ENABLED

    @enabled.setter
    def enabled(self, value: bool) -> None:
        pass  # the state machine decides

    @property  # type: ignore[override]
    def alarm_code(self) -> int:
        """The device's error code while it is in a fault."""
        device = getattr(self, "device", None)
        if device is None:
            return 0
        state = device.state_at()
        return device.error_code if state in (State.FAULT, State.FAULT_REACTION_ACTIVE) else 0

    @alarm_code.setter
    def alarm_code(self, value: int) -> None:
        device = getattr(self, "device", None)
        if device is not None and value == 0:
            device.error_code = 0

    @property  # type: ignore[override]
    def homed(self) -> bool:
        """A homing of the device completed (its reference is set)."""
        device = getattr(self, "device", None)
        return device is not None and device.homed

    @homed.setter
    def homed(self, value: bool) -> None:
        pass  # the device's homing decides

    def position(self, now: float | None = None) -> int:
        return signed32(round(self.device.position(time_or_present(now))))

    def physical_position(self, now: float | None = None) -> float:
        return self.device.physical_position(time_or_present(now))

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        return self.device.switch_states(now)

    def is_moving(self, now: float | None = None) -> bool:
        return self.device.is_moving(time_or_present(now))

    def velocity(self, now: float | None = None) -> float:
        return self.device.velocity(time_or_present(now))

    def advance(self, now: float) -> None:
        self.device.advance(now)

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """A fault with error code ``code``."""
        self.device.raise_fault(code, time_or_present(now))

    def power_loss(self) -> None:
        super().power_loss()
        self.device.power_loss(monotonic())

    def power_restore(self) -> None:
        SimDrive.power_restore(self)
        self.regs = dict(self.eeprom)
        self.device.power_restore(monotonic())

    # -- registers ---------------------------------------------------------------------------

    def _object_at(self, address: int) -> str | None:
        w = self._words.get(address)
        if w is None or w.reg.d.object is None:
            return None
        return object_name(w.reg.d.object)

    def read_register(self, address: int, now: float) -> int:
        name = self._object_at(address)
        if name is None:
            return super().read_register(address, now)
        reg = self._words[address].reg
        value = self.device.read(name, now)
        for b in reg.d.bits.values():  # a drive's own flags beside the object's bits
            on = self._eval(b.twin, now) if b.twin is not None else \
                self.homed if b.means == "homed" else None
            if on is not None:
                value = value | b.mask if on else value & ~b.mask
        words: dict[int, int] = {}
        self._store(words, reg, None, value)
        return words[address]

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Plain registers as in any twin; objects checked whole, then written in address
        order (a 32-bit object needs both its words in the request or stored)."""
        self.check_write(address, values)
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        objects: list[tuple[str, int]] = []
        plain: list[tuple[int, int]] = []
        seen: set[str] = set()
        for a, word in written.items():
            name = self._object_at(a)
            if name is None:
                plain.append((a, word))
                continue
            if name in seen:
                continue
            seen.add(name)
            reg = self._words[a].reg
            objects.append((name, self._raw(reg, None, {**self.regs, **written})))
        for name, value in objects:
            self.device.check(name, value)
        if plain:
            start = plain[0][0]
            if [a for a, _ in plain] == list(range(start, start + len(plain))):
                super().write_registers(start, [w for _, w in plain], now)
            else:
                for a, w in plain:
                    super().write_registers(a, [w], now)
        for a, word in written.items():
            if self._object_at(a) is not None:
                self.regs[a] = word
        for name, value in objects:
            self.device.write(name, value, now)


def _pulses_per_raw(d: Description, kind: str, ppr: int) -> float:
    """Pulses/s (or /s²) of one raw unit of the description's velocity (acceleration)
    objects."""
    names = ("profile_velocity", "target_velocity", "velocity_actual_value",
             "homing_speed_search") if kind == "velocity" else (
        "profile_acceleration", "profile_deceleration", "homing_acceleration")
    for name in names:
        reg = d.objects.get(name)
        if reg is None:
            continue
        v = float(reg.codec.to_physical(1, ppr=ppr))
        if reg.codec.kind is Kind.SPEED:
            return v * ppr / 60.0
        if reg.codec.kind is Kind.ACCEL:
            return v * ppr
        return v
    return 1.0
