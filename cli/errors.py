"""The command line's own errors (the exit code each one ends with is ``cli.main``'s)."""

from tracer.errors import TilerenderError


class UsageError(TilerenderError, ValueError):
    """A problem with the command line or its inputs, reported in one line."""


class CommandFailed(TilerenderError, RuntimeError):
    """A valid command that could not complete (e.g. the cluster lost every tracer)."""
