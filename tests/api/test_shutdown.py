"""`docker stop` sends SIGTERM: the service shuts down through its own handler (Ray's core, which
installs a handler of its own when it starts, must not dump a stack and kill the process)."""

import signal

from tests.api.conftest import start_server


def test_sigterm_stops_the_server_gracefully(tmp_path):
    server = start_server(tmp_path / "data", "--tracers", "1", "--threads", "1")
    server.process.send_signal(signal.SIGTERM)
    server.process.wait(60)
    stderr = server.process.stderr.read()
    assert "SIGTERM received" not in stderr, stderr[-2000:]
    assert "Traceback" not in stderr, stderr[-2000:]
    assert server.process.returncode in (0, -signal.SIGTERM), stderr[-2000:]
