"""The one error hierarchy of detcal.

Library code raises these; only the CLI turns them into exit codes
(``UsageError`` -> 2, ``DataError`` -> 1) and one-line messages.
"""

from __future__ import annotations


class DetcalError(Exception):
    """Base of every error detcal raises on purpose.

    The message names the file, line or field and says what was expected.
    """

    exit_code = 1


class DataError(DetcalError):
    """The input data is malformed: bad log line, truncated file, NaN range..."""

    exit_code = 1


class UsageError(DetcalError):
    """The user asked for something inconsistent: unknown topic, bad option, missing file."""

    exit_code = 2
