"""Errors and warnings raised by the recording loaders."""
from __future__ import annotations


class RecordingFormatError(ValueError):
    """A file that cannot be read as the format it claims to be.

    The message always names the file and, where it applies, the line number or the
    field, so that a person can open the file and see the problem.
    """

    def __init__(self, path: str, problem: str, line: int | None = None, field: str | None = None):
        self.path = str(path)
        self.problem = problem
        self.line = line
        self.field = field
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field {field!r}"
        super().__init__(f"{where}: {problem}")


class RecordingWarning(UserWarning):
    """Something in a file was repaired or skipped; the recording still loaded.

    Every such note is also kept in ``Recording.warnings`` so that it travels with the data.
    """
