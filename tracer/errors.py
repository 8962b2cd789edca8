"""The one exception bad input raises, and the one-line message of a validation error."""

import pydantic


class SceneError(ValueError):
    """A scene, mesh or setting that cannot be rendered; ``str()`` is a one-line explanation."""


def format_validation_error(error: pydantic.ValidationError) -> str:
    """One line naming the first problem (and how many more there are)."""
    errors = error.errors()
    first = errors[0]
    parts = [str(p) for p in first["loc"] if not str(p).startswith(("tagged-union[", "function-"))]
    where = ".".join(parts) or "scene"
    message = first["msg"]
    if first["type"] == "extra_forbidden":
        message = "unknown key"
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    return f"{where}: {message}{more}"
