"""The ``tilerender`` command line."""
