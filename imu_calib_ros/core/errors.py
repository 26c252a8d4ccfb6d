"""Exception types raised at the boundary (files, arguments, input data).

Every error carries one line that says what is wrong and, where known, the file and key,
so the CLI and the nodes can print it as it is.
"""
from __future__ import annotations


class ImuCalibError(Exception):
    """Base class: a user-facing error with a one-line message."""


class ConfigError(ImuCalibError):
    """A configuration, fixture, plan, grade or calibration file is unusable.

    Parameters
    ----------
    message:
        What is wrong (and what to do, if that is not obvious).
    source:
        The file (or other origin, e.g. ``'parameter'``) the value came from.
    key:
        Dotted key path inside the file, e.g. ``'joints[1].axis'``.
    """

    def __init__(self, message: str, source: str | None = None, key: str | None = None):
        self.source = source
        self.key = key
        where = ''
        if source:
            where += f'{source}'
        if key:
            where += f'{": " if where else ""}{key}'
        super().__init__(f'{where}: {message}' if where else message)


class PlanError(ImuCalibError):
    """A motion plan cannot be run on the given fixture (names the step and the reason)."""


class BagError(ImuCalibError):
    """A bag is missing, empty, corrupt, or lacks the topics or types we need."""


class InputError(ImuCalibError):
    """Measurement data that cannot give a calibration (no motion, unknown joints, ...)."""


class SelfCheckError(ImuCalibError):
    """A run finished but its own evidence says the result cannot be trusted (issue 17): the
    self-check's one line; the CLI exits with :attr:`exit_status` (3, not 2: the input was
    usable) and writes nothing unless forced."""

    exit_status = 3
