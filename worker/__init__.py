"""Brigade tracers: a scene replica that follows the cluster's commits, and (next) the Ray actor
that renders line ranges with it. Knows nothing of HTTP or balancing."""
