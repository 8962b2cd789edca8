"""The root of tilerender's errors, the one bad input raises, and a validation error's message.

Every error tilerender raises on purpose derives from :class:`TilerenderError`, whatever layer
raises it (``cluster.errors``, ``worker``, ``api.errors``, ``cli``); anything else that escapes
is a bug. Domain errors also derive from the built-in they refine (``ValueError`` for bad input,
``RuntimeError`` for a cluster that cannot finish), so callers may catch either.
"""

import pydantic


class TilerenderError(Exception):
    """Root of tilerender's own errors; ``str()`` is a one-line message for the user."""


class SceneError(TilerenderError, ValueError):
    """A scene, mesh or setting that cannot be rendered; ``str()`` is a one-line explanation."""


UNNAMED_TAGS = {"camera": {"view", "file"}}
"""Union tags a location leaves out: a camera's kind is told by its keys, it has no ``type``."""


def format_validation_error(error: pydantic.ValidationError) -> str:
    """One line naming the first problem (and how many more there are)."""
    errors = error.errors()
    first = errors[0]
    loc = [str(p) for p in first["loc"]]
    parts = [
        p
        for i, p in enumerate(loc)
        if not p.startswith(("tagged-union[", "function-"))
        and not (i > 0 and p in UNNAMED_TAGS.get(loc[i - 1], ()))
    ]
    where = ".".join(parts) or "scene"
    message = first["msg"]
    if first["type"] == "extra_forbidden":
        message = "unknown key"
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    return f"{where}: {message}{more}"
