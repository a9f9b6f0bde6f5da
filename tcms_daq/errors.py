"""Exception types of the core. Each message is one line a test engineer can act on."""

from __future__ import annotations


class TcmsError(Exception):
    """Base class of every error TCMS-DAQ raises on purpose."""


class ConfigError(TcmsError):
    """Invalid configuration: the message names the file, the key and the problem."""


class DataFormatError(TcmsError):
    """A data file or array set that cannot be used: the message names the problem (column, row, count)."""


class EvaluationError(TcmsError):
    """The data are well-formed but cannot be evaluated (e.g. no full hysteresis loop)."""
