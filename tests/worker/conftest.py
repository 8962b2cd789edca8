"""Fixtures of the worker tests."""

import pytest

from cluster.connect import connect, disconnect


@pytest.fixture(scope="module")
def ray_session():
    """One embedded Ray for the module (started only if this process has none)."""
    connection = connect(num_cpus=2)
    yield connection
    if connection.started:
        disconnect()
