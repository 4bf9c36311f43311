"""The project's own error types: every failure a user can cause is one of these.

The CLI prints ``str(error)`` on one line and exits with code 2; nothing else is caught, so a
raw traceback always means a bug in pcpg-dist, never a mistake in the user's input.
"""

from __future__ import annotations


class PcpgError(Exception):
    """Base of every error caused by user input (config, data, level files, services)."""


class ConfigError(PcpgError):
    """An experiment config is invalid: the message names the key, the value and what is allowed."""


class DataError(PcpgError):
    """A dataset, play log or model file is missing, corrupt or of the wrong shape."""


class LayoutError(PcpgError):
    """A level or layout file is malformed: the message names the file and the line."""


class TrainingError(PcpgError):
    """Training diverged (non-finite weights or loss): the message names the cell and the
    hyper-parameters to change; nothing trained by that run is published."""


class ServiceError(PcpgError):
    """A tracking server, Ray cluster or study storage cannot be reached or used."""
