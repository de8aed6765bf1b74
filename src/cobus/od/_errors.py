"""Errors of the object dictionary layer and the findings an EDS/DCF check reports."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from cobus.errors import CobusError

__all__ = [
    "DataLengthError",
    "DataTypeError",
    "EdsError",
    "Finding",
    "Severity",
    "ValueRangeError",
]


class ValueRangeError(CobusError, ValueError):
    """A value that the data type (or the object's limits) cannot hold, or of the wrong type."""


class DataLengthError(CobusError, ValueError):
    """Encoded data whose length does not match what the data type takes."""


class DataTypeError(CobusError, ValueError):
    """A data type number that CiA 301 does not define as a basic type."""


class Severity(enum.Enum):
    """How bad a finding is: errors make strict loading fail, warnings never do."""

    ERROR = "error"
    WARNING = "warning"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, slots=True)
class Finding:
    """One problem found in an EDS/DCF file, located like a compiler message."""

    path: str
    line: int | None
    section: str | None
    severity: Severity
    reason: str

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        sect = f" [{self.section}]" if self.section else ""
        return f"{where}:{sect} {self.severity}: {self.reason}"


class EdsError(CobusError):
    """An EDS/DCF file that cannot be read as it stands: where it is and what to fix."""

    path: str
    line: int | None
    section: str | None
    reason: str

    def __init__(self, path: str, line: int | None, section: str | None, reason: str) -> None:
        self.path = path
        self.line = line
        self.section = section
        self.reason = reason
        where = path if line is None else f"{path}:{line}"
        sect = f" [{section}]" if section else ""
        super().__init__(f"{where}:{sect} {reason}")

    @classmethod
    def from_finding(cls, finding: Finding) -> EdsError:
        return cls(finding.path, finding.line, finding.section, finding.reason)
