"""Tools that compare tilerender with an independent renderer (tests and bench use them)."""
