"""``[[examples]]``: the frames the manual prints and what each stands for (``drivebus
drive check`` runs them: ``drivebus.drives.examples``).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BeforeValidator, Field, model_validator

from drivebus.drives.description.fields import Source, _Model


def _frames(v: Any) -> Any:
    return [v] if isinstance(v, str) else v


class ExampleDef(_Model):
    """``[[examples]]``: a frame the manual prints and what it stands for; ``drivebus
    drive check`` verifies that the engine sends exactly those bytes for it and decodes
    the printed reply to the printed values (``drivebus.drives.examples``)."""

    doc: str = Field("", description="what the manual says the frame does")
    source: Source | None = Field(None, description="where the manual prints it")
    request: Annotated[list[str], BeforeValidator(_frames)] = Field(
        min_length=1, description="the request frame(s) as printed: '01 06 00 1D 02 58 D9 8B' "
        "(RTU, CRC included) or an MBAP frame; several: in the order the engine sends them")
    reply: Annotated[list[str], BeforeValidator(_frames)] = Field(
        [], description="the reply frame(s) as printed, for the requests in order")
    write: dict[str, Any] | None = Field(None, description="what the request writes: "
                                         "register = value (physical, as a procedure's)")
    raw: bool = Field(False, description="write: the values are what the registers hold")
    block: bool = Field(False, description="write: in one FC16 (the registers form a block)")
    read: list[str | list[str]] | None = Field(None, description="what the request reads: "
                                               "register keys, or spans [first, last]")
    procedure: str | None = Field(None, description="the procedure the frames stand for")
    args: dict[str, Any] = Field({}, description="procedure: its arguments (drive units)")
    values: dict[str, Any] = Field({}, description="read: what the reply decodes to "
                                   "(physical values)")
    pulses_per_rev: int | None = Field(None, gt=0, description="the pulses per revolution "
                                       "the example assumes (default: the description's)")
    options: dict[str, Any] = Field({}, description="drive_options the example assumes")
    erratum: str = Field("", description="what the manual got wrong in it (a printed CRC, "
                         "an address of another model's map): a wrong CRC is then checked "
                         "as corrected, and an example that stands for nothing the drive "
                         "does is listed, not run")

    listed: str = Field("", description="why the example is listed but not run (a frame "
                        "with a bad CRC on purpose, an address the description leaves out, a "
                        "value the engine refuses before sending)")

    @model_validator(mode="after")
    def _one(self) -> ExampleDef:
        given = [k for k in ("write", "read", "procedure") if getattr(self, k) is not None]
        if not given and (self.erratum or self.listed):
            return self  # printed, but standing for nothing this drive does: said, not run
        if len(given) != 1:
            raise ValueError("an example stands for exactly one of write, read or procedure "
                             f"(got {', '.join(given) or 'none'})")
        if self.values and self.read is None:
            raise ValueError("values are what a read's reply decodes to: give read")
        return self
