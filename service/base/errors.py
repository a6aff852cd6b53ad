"""The project's one exception hierarchy.

Every error raised on purpose by Holo-realizer code derives from :class:`HoloError`,
so a caller can catch everything the library reports with one ``except`` clause
and still tell the kinds apart.  The classes below are shared across packages; a few
errors of one package's own live beside their code and derive from :class:`HoloError`
too: ``service.galilean.GalileanError``, ``game.scene.SceneError`` and
``game.highscores.HighScoreFileError``.  This module is the bottom layer: it imports
nothing of the project.
"""

from __future__ import annotations


class HoloError(Exception):
    """Base class of every error Holo-realizer raises on purpose."""


class MeshFileError(HoloError):
    """A mesh, object or scene file could not be read.

    Parameters
    ----------
    path : str
        The file that was being read.
    where : str
        The line (``"line 12"``) or element (``"face 7"``) at fault, or ``""``.
    reason : str
        What was wrong, in words.
    """

    def __init__(self, path: str, where: str, reason: str) -> None:
        self.path = str(path)
        self.where = where
        self.reason = reason
        loc = f"{self.path}, {where}" if where else self.path
        super().__init__(f"{loc}: {reason}")


class MeshError(HoloError):
    """A mesh held in memory is invalid (bad indices, non-finite vertices...)."""


class SettingsError(HoloError, ValueError):
    """A setting is out of its documented range."""


class RenderError(HoloError):
    """The render pipeline could not produce a frame."""


class ProtocolError(HoloError):
    """Bytes or a message did not follow the documented protocol."""


class DeviceError(HoloError):
    """A device (serial port, simulated device) failed or could not be opened."""


class LogFileError(HoloError):
    """A recorded session log is unreadable or torn."""


class PngError(HoloError, ValueError):
    """An image cannot be written as PNG, or PNG bytes cannot be decoded."""


class SampleError(HoloError, ValueError):
    """A pose sample or its time is unusable (non-finite, backwards, duplicate)."""


class CodedError(HoloError):
    """An error with one of the protocol's error codes (``docs/protocol.md`` 1.3).

    Parameters
    ----------
    code : str
        The error code (``bad_json``, ``bad_array``, ``warming_up``...).
    message : str
        What was wrong, in words.
    """

    def __init__(self, code: str, message: str) -> None:
        self.code = code
        self.message = message
        super().__init__(f"{code}: {message}")


class MessageError(CodedError, ProtocolError):
    """A service message broke the protocol (``docs/protocol.md``): ``code``, ``message``."""


class ServiceError(CodedError):
    """The render service answered a request with an error reply (its code and message)."""


class ServiceUnavailableError(ServiceError):
    """The render service did not answer within the client's retries."""

    def __init__(self, message: str) -> None:
        super().__init__("unavailable", message)
