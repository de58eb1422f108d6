"""Argument types the commands share: a bad value is argparse's usage error (exit 2) naming the
option, before the command loads or opens anything."""

from __future__ import annotations

import argparse


def seed(text: str) -> int:
    """A random seed: a whole number, 0 or more."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a seed: expected a whole number, 0 or more")
    return value


def job_id(text: str) -> str:
    """A job id / VIN: some text, without control characters (station/records/printable.py)."""
    from station.records.printable import escaped, unprintable

    if not text.strip():
        raise argparse.ArgumentTypeError("the job id is empty; leave out --job for a cycle without one")
    bad = unprintable(text)
    if bad:
        raise argparse.ArgumentTypeError(
            f"the job id {text!r} holds {' '.join(escaped(c) for c in bad)}: control characters (or bytes that "
            "are not UTF-8) would forge or hide lines in the history, the CSV and the report; "
            "type the job id without them")
    return text
