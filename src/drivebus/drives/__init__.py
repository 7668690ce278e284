"""Drive profiles: one module per drive family on a shared base."""

from drivebus.drives.base import DriveProfile, HomingParams, MoveParams
from drivebus.drives.registers import Access, Register, WordOrder, join_words, split_words
from drivebus.drives.status import DriveIdentity, DriveStatus

__all__ = [
    "Access",
    "DriveIdentity",
    "DriveProfile",
    "DriveStatus",
    "HomingParams",
    "MoveParams",
    "Register",
    "WordOrder",
    "join_words",
    "split_words",
]
