"""The ``tilerender`` sub-commands, one module each with ``run(args) -> int`` (see ``cli.main``)."""
