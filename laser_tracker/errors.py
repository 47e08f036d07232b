"""Errors that reach the user as one clear line and a non-zero exit status."""
from __future__ import annotations


class LaserTrackerError(Exception):
    """Base of the errors the command-line tools report without a traceback."""


class InputFileError(LaserTrackerError):
    """A file that cannot be read as what it should be; names the file and where it broke."""

    def __init__(self, path, reason: str, location: str | None = None):
        reason = ' '.join(str(reason).split())   # one line, whatever the library said
        self.path, self.reason, self.location = str(path), reason, location
        where = f'{self.path}: {location}' if location else self.path
        super().__init__(f'{where}: {reason}')
