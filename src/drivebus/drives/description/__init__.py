"""Drive descriptions: a drive family as data (TOML), validated into typed models.

A description says everything a profile says: who the drive is and how a scan knows it,
its link (baud rates, formats, addresses, function codes, word order, exception texts),
its registers (address, width, sign, unit, range, access, EEPROM wear, volatility), its
units, how its status decodes into ``DriveStatus``, its procedures as ordered steps, its
homing methods, what it cannot do and why, and how it behaves (for its simulated twin).
An engine (``drivebus.drives.engine``) interprets it as a ``DriveProfile``;
``drivebus.sim.described`` builds a twin from the same file.

The format's reference is ``docs/reference/descriptions.md``; the built-in families are
the files in ``drivebus/drives/descriptions/``. ``load_description`` reads and checks one
file: any mistake is one ``ConfigError`` naming the file, the key path and the problem.

One room per section, each model with its own validators: ``fields`` (the pieces all
sections use), ``link`` (``[drive]``, ``[identify]``, ``[link]``), ``registers``,
``options`` (``[options]``, ``[units]``, ``[eeprom]``, ``[programs]``), ``status``
(``[status]``, ``[inputs]``/``[outputs]``, ``[alarms]``, ``[signals]``), ``homing``,
``procedures``, ``twin``, ``objects`` (``[cia402]``), ``examples``; ``model`` (the whole
``Description`` and its views); ``mapping`` (where its registers sit on the wire: the
names of an address range, the blocks a write may merge); ``checks`` (the cross-checks,
which need the whole description, one room per section); ``loading`` (files, ``extends``,
parsing). This package's names are the format's public names.
"""

from drivebus.drives.description.examples import ExampleDef
from drivebus.drives.description.fields import (
    FORMAT_VERSION,
    SOURCE_KINDS,
    E,
    IntKeyed,
    Scale,
    Source,
    T,
    Unit,
    Word,
    source_kind,
)
from drivebus.drives.description.homing import HomingDef, HomingMethod
from drivebus.drives.description.link import (
    DriveInfo,
    FormatRule,
    Identify,
    Link,
    ParameterNumbers,
    Refusals,
    Timing,
)
from drivebus.drives.description.loading import load_description, parse_description, read_toml
from drivebus.drives.description.model import Description
from drivebus.drives.description.objects import Cia402Def, ObjectUnit, object_name
from drivebus.drives.description.options import (
    EepromDef,
    OptionCheck,
    OptionDef,
    ProgramsDef,
    PulsesPerRev,
    Units,
    WriteThroughDef,
)
from drivebus.drives.description.procedures import (
    EXTRA_PROCEDURES,
    PROCEDURES,
    Param,
    Priorities,
    Procedure,
    Step,
    WriteItem,
)
from drivebus.drives.description.registers import TWIN_MEANINGS, BitDef, Reg, RegisterDef
from drivebus.drives.description.status import (
    AlarmsDef,
    CompletionDef,
    IoDef,
    PollDef,
    SignalDef,
    StatusDef,
)
from drivebus.drives.description.twin import (
    TWIN_ACTIONS,
    InputTrigger,
    LimitsDef,
    Trigger,
    TwinDef,
    TwinHomingDef,
)

__all__ = [
    "PROCEDURES",
    "SOURCE_KINDS",
    "TWIN_ACTIONS",
    "TWIN_MEANINGS",
    "Description",
    "ExampleDef",
    "Reg",
    "Step",
    "load_description",
    "parse_description",
    "source_kind",
]
# Every other section model stays importable from here, as from the one module it was.
_SECTIONS = (
    FORMAT_VERSION, E, IntKeyed, Scale, Source, T, Unit, Word, HomingDef, HomingMethod,
    DriveInfo, FormatRule, Identify, Link, ParameterNumbers, Refusals, Timing, read_toml,
    Cia402Def, ObjectUnit, object_name, EepromDef, OptionCheck, OptionDef, ProgramsDef,
    PulsesPerRev, Units, WriteThroughDef, EXTRA_PROCEDURES, Param, Priorities, Procedure,
    WriteItem, BitDef, RegisterDef, AlarmsDef, CompletionDef, IoDef, PollDef, SignalDef,
    StatusDef, InputTrigger, LimitsDef, Trigger, TwinDef, TwinHomingDef,
)
