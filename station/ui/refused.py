"""A request the screen refuses: the HTTP status, the sentence, and what to do."""

from __future__ import annotations


class Refused(Exception):
    def __init__(self, status: int, message: str, hint: str | None = None):
        super().__init__(message)
        self.status, self.hint = status, hint
