"""Cia402Device: a simulated CiA 402 drive addressed by object names, not registers.

Whatever maps CiA 402 objects onto a bus (a generic twin built from a drive description,
a test) reads and writes the device by object name (``drivebus.drives.cia402.OBJECTS``)
and gets values of the objects' data types; refusals raise ``SlaveException`` with the
codes given (the twin's own). The device runs the device control state machine of
CiA 402-2 / IEC 61800-7-201 (the transition table of ``drivebus.drives.cia402``),
profile position with the new-set-point handshake, profile velocity and homing, on the
simulator's real-time kinematics (``Kinematics``, as the other twins); its state is
computed lazily at each access (``advance``), so no task runs behind it.

Choices where the profile leaves room (documented here, asserted in tests/test_cia402.py):

* commands act on the controlword as written (bits 0-3, 7; fault reset on the rising edge
  of bit 7); enable operation in Ready to switch on is ignored unless ``switch_on_enables``;
  transition 16 (Quick stop active -> Operation enabled) needs quick stop option code 5-8;
* leaving Operation enabled by shutdown or disable voltage releases the motor at once;
  disable operation (transition 5) ramps it down with the profile deceleration;
* quick stop follows the quick stop option code (605Ah: 0, 3, 4, 7, 8 at once; 1, 5 with
  the profile deceleration; 2, 6 with the quick stop deceleration; 1-4 then go to Switch
  on disabled when stopped); a fault goes through Fault reaction active while the motor
  stops on the quick stop deceleration (0: at once), then to Fault; a fault reset clears it;
* profile position: one set-point may wait behind the one in progress (set-point
  acknowledge stays 1 while it waits); change set immediately replaces the motion at once;
  change on set-point (bit 9) is taken as a stop at each set-point; a relative target adds
  to the last target, or to the actual position after a motion that ended short (halt,
  quick stop, limit switch, disable); a set-point whose profile velocity, acceleration or
  deceleration is 0 is acknowledged but never moves (target reached stays 0);
* target reached (bit 10): profile position, standing at the target or stopped after a
  halt or a limit switch; profile velocity, at the target velocity or stopped by a halt;
  homing, as the homing status table says; other states, standing still;
* halt (bit 8) decelerates per the halt option code (605Dh: 1 profile deceleration, 2
  quick stop deceleration, 3 and 4 at once) and holds; profile position drops its
  waiting set-point (a new edge of bit 4 is ignored while halt is set) and continues the
  interrupted one to its target when halt clears without a new set-point (CiA 402-2:
  "positioning shall be executed or continued"), profile velocity resumes
  the target velocity when halt clears, homing is interrupted (as by bit 4 falling);
* a limit switch (60FDh bits 0, 1) in the way stops a profile position or velocity motion
  on the quick stop deceleration and sets internal limit active (bit 11) while active; a
  motion toward an active limit switch does not start; the axis may only leave it; while
  the axis still stops into a limit switch, a new set-point or target velocity waits for
  the stop to end, and no other stop ramps slower than the quick stop;
* homing starts from standstill (else a homing error); the legs that search a switch run
  at the search speed, the final approach over the homing edge (and on to the index
  pulse) at the zero speed, all on the homing acceleration. The drive decides from its
  inputs as a real one: a method's home switch side (positive, negative, over part of
  the travel) is its assumption, the switch positions are the machine's. It reverses
  once on the method's reversal limit switch; any other limit switch met is a homing
  error (stop on the quick stop deceleration). At the home position the position actual
  value becomes the home offset and the axis comes to rest on the homing acceleration;
  35 and 37 take the current position;
* a mode of operation written takes effect at once (the motion of the previous mode stops
  on the profile deceleration); modes other than the supported ones are refused;
* power loss: the motor stops at once; at power-up the device is in Not ready to switch
  on for ``boot_time``, then Switch on disabled; objects return to their factory values
  except ``retained`` ones; the position counter starts at 0 (incremental encoder) unless
  ``absolute_encoder``; the axis is no longer homed.

In rooms: ``state`` (the setup, factory values, the records of work under way),
``base`` (objects, the axis, the statusword, faults and power), ``machine`` (the state
machine, mode bits, events in time), ``profiles`` (PP, PV, limit switches), ``homing``;
``device`` puts them together.
"""

from __future__ import annotations

from drivebus.sim.cia402_device.device import Cia402Device
from drivebus.sim.cia402_device.state import FACTORY_VALUES, Cia402Setup

__all__ = ["FACTORY_VALUES", "Cia402Device", "Cia402Setup"]
