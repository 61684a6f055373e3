"""User-facing errors: one line that names the file, the record and what is wrong."""

from __future__ import annotations

from pathlib import Path


class ToolkitError(Exception):
    """An error the user can act on; the CLI prints it as one line and exits 1."""

    def __init__(
        self, what: str, *, file: str | Path | None = None, record: str | int | None = None
    ) -> None:
        self.what = what
        self.file = None if file is None else str(file)
        self.record = record
        super().__init__(self.line())

    def line(self) -> str:
        where = ""
        if self.file is not None:
            where = self.file
            if self.record is not None:
                where += f":{self.record}" if isinstance(self.record, int) else f" ({self.record})"
            where += ": "
        elif self.record is not None:
            where = f"{self.record}: "
        return where + self.what


class FormatError(ToolkitError):
    """The input is not of the format it claims to be, or is damaged beyond skipping."""


class OutputExistsError(ToolkitError):
    """The output exists and --force was not given."""
