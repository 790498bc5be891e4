"""Exceptions of hapticctrl: each carries VirtuoseAPI's error code
(``VIRT_E_*``, as ``virtGetErrorCode`` returns it) and the library's message."""

from __future__ import annotations

# VirtuoseAPI's error codes (VirtuoseAPI.h) that hapticctrl reports.
VIRT_E_NO_ERROR = 0
VIRT_E_COMMUNICATION_FAILURE = 2
VIRT_E_INVALID_CONTEXT = 3
VIRT_E_FILE_NOT_FOUND = 4
VIRT_E_TIME_OUT = 6
VIRT_E_VARIABLE_NOT_AVAILABLE = 8
VIRT_E_INCORRECT_VALUE = 9
VIRT_E_SYNTAX_ERROR = 10
VIRT_E_WRONG_MODE = 17


class VirtuoseError(Exception):
    """Base class: ``code`` is VirtuoseAPI's error code, ``message`` the text."""

    code: int
    message: str

    def __init__(self, code: int, message: str, **extra: object) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        for k, v in extra.items():
            setattr(self, k, v)

    def __str__(self) -> str:
        return f"{self.message} (VirtuoseAPI error {self.code})"


class AddressError(VirtuoseError, ValueError):
    """The address does not parse or resolve (``VIRT_E_SYNTAX_ERROR``)."""


class CommunicationError(VirtuoseError):
    """A socket operation failed (``VIRT_E_COMMUNICATION_FAILURE``)."""


class ControllerTimeoutError(VirtuoseError, TimeoutError):
    """No reply from the controller in time (``VIRT_E_TIME_OUT``); also what
    a client with the wrong key gets: the bridge answers nothing."""


class RefusedError(VirtuoseError):
    """The controller refused a request: ``request``, ``reason`` (the
    protocol's reason code) and ``reason_name``. Code ``VIRT_E_WRONG_MODE``
    when the bridge cannot take the handshake now (0x101),
    ``VIRT_E_COMMUNICATION_FAILURE`` for no session (an unauthenticated
    session; an authenticated one raises ``SessionEndedError``), else
    ``VIRT_E_INCORRECT_VALUE``."""

    request: str
    reason: int
    reason_name: str


class SessionEndedError(CommunicationError):
    """The controller ended the session (``VIRT_E_COMMUNICATION_FAILURE``):
    ``reason`` is the protocol's code and ``reason_name`` its text: 0x102
    another key holder's handshake took it, 0x103 it expired (the client was
    silent too long), 0x104 its sequence numbers are spent, 0x100 the
    controller has no session (a fail-safe, a stop). Every call but
    ``close()`` then raises it; open a new ``Session``."""

    reason: int
    reason_name: str


class InvalidArgumentError(VirtuoseError, ValueError):
    """A parameter is invalid: NaN, out of range, wrong shape, unreadable key
    file (``VIRT_E_INCORRECT_VALUE``)."""


class NoDataError(VirtuoseError):
    """No answer from the controller yet (``VIRT_E_VARIABLE_NOT_AVAILABLE``)."""


class ClosedError(VirtuoseError):
    """The session is closed (``VIRT_E_INVALID_CONTEXT``)."""


class NoKeyError(VirtuoseError):
    """No key was given and ``insecure=True`` was not asked for
    (``VIRT_E_FILE_NOT_FOUND``)."""
