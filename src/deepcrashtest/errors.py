"""Exceptions that the CLI turns into one line on stderr and exit code 2."""

from __future__ import annotations


class UserError(Exception):
    """Bad input from the user (file, argument, data). Printed as one line, exit code 2."""


class ScenarioError(UserError, ValueError):
    """A Scenario file or object is invalid; the message names the field."""
