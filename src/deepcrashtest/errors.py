"""Exceptions that the CLI turns into one line on stderr and exit code 2."""

from __future__ import annotations

import numbers


class UserError(Exception):
    """Bad input from the user (file, argument, data). Printed as one line, exit code 2."""


class ScenarioError(UserError, ValueError):
    """A Scenario file or object is invalid; the message names the field."""


def check_seed(seed: object) -> int:
    """The one rule for seeds everywhere: a non-negative integer (numpy's generators refuse negatives)."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or int(seed) < 0:
        raise UserError(f"--seed must be a non-negative integer (got {seed!r})")
    return int(seed)
