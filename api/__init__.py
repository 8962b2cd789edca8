"""tilerender's HTTP service: scenes, jobs, interactive sessions, the cluster (docs/api.md)."""
