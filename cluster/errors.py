"""The cluster's errors, under :class:`tracer.errors.TilerenderError`."""

from tracer.errors import TilerenderError


class ClusterError(TilerenderError, RuntimeError):
    """A frame cannot be completed (no tracer left, a range failing again and again), or no
    tracer would start; ``str()`` says which."""


class ClusterUnreachable(TilerenderError, ConnectionError):
    """The Ray cluster at an address cannot be reached; ``str()`` says which and why."""
