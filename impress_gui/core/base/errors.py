"""Typed errors with stable codes.

Every error a user can meet carries a short code (``E-...``) that the documentation's
troubleshooting section lists, so a message seen in the window or the console can be looked up.
"""

from __future__ import annotations

from impress_gui.core.base import codes


class ImpressError(Exception):
    """Base of all errors reported to users; ``code`` is stable and documented."""

    code = codes.E_GENERIC

    def __init__(self, message: str, *, code: str | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code


class InputError(ImpressError):
    """A file or value given by the user is unusable (wrong type, damaged, out of range)."""

    code = codes.E_INPUT


class FormatError(InputError):
    """A JSON/TIFF/PLY/X3P file is damaged, of the wrong kind or of an unknown version."""

    code = codes.E_FORMAT


class VideoError(InputError):
    """A video cannot be opened or decoded, or is truncated."""

    code = codes.E_VIDEO


class CalibrationError(ImpressError):
    """Calibration inputs are inconsistent or the geometry is degenerate."""

    code = codes.E_CALIB


class ReconstructionError(ImpressError):
    """Processing cannot produce a result (e.g. a stripe is never found)."""

    code = codes.E_RECON


class IntegrityError(ImpressError):
    """An evidence file changed since it was registered, or a log chain is broken."""

    code = codes.E_INTEGRITY


class Cancelled(Exception):  # noqa: N818 - the name is the contract
    """Raised inside a long task when its cancel token is set. Not an error."""
