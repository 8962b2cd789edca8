"""The cluster side of tilerender: the authoritative, versioned scene graph and its commit log
(``scene_graph``); the coordinator, balancers and frame assembly join it later."""
