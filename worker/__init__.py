"""Brigade tracers: a scene replica that follows the cluster's commits (``replica``) and the Ray
actor that renders line ranges with it (``tracer_actor``). Knows nothing of HTTP or balancing."""
