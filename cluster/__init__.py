"""The cluster side of tilerender: the authoritative, versioned scene graph and its commit log
(``scene_graph``), joining or starting Ray (``connect``), the coordinator that schedules frames
on tracer actors and survives their failures (``coordinator``), frame assembly (``assembler``)
and the workload balancers (``balance``). See docs/cluster.md."""
