"""The simplify package's own error (derives from :class:`service.base.errors.HoloError`)."""

from __future__ import annotations

from service.base.errors import HoloError


class SimplifyError(HoloError, ValueError):
    """A simplification was asked with bad input (no faces, EPS <= 0, a bad fraction)."""
