"""Exceptions raised by tiltrov_ros.

All of them derive from :class:`TiltrovError`; the ones about bad values also
derive from :class:`ValueError`, so callers that only know the standard library
still catch them.
"""

from __future__ import annotations


class TiltrovError(Exception):
    """Base class of every error raised by tiltrov_ros."""


class ParameterError(TiltrovError, ValueError):
    """A parameter has a wrong type, is out of range or is missing.

    The message names the parameter, the value received and the allowed range;
    ``source`` names the file it came from, when there is one.
    """

    def __init__(self, name: str, message: str, *, source: str | None = None) -> None:
        self.name = name
        self.source = source
        where = f' (in {source})' if source else ''
        super().__init__(f'parameter {name!r}{where}: {message}')


class UnreadableFileError(TiltrovError, ValueError):
    """A file given or edited by the user cannot be read as YAML (the message names it)."""


class ScenarioError(TiltrovError, ValueError):
    """A scenario file or scenario description is invalid."""


class CampaignError(TiltrovError, ValueError):
    """A campaign file is invalid (the message names the file and the key)."""


class AllocationError(TiltrovError, ValueError):
    """An allocation request is malformed (wrong shape, non-finite values)."""


class BagError(TiltrovError):
    """A bag cannot be written, read or repaired."""
