"""Joining a cluster by ``host:port`` needs a Ray node on this machine: without one,
``connect`` says so at once instead of letting Ray wait a minute or two. The embedded Ray
listens on the loopback interface only."""

import ipaddress
import socket
import struct
import threading

import psutil
import pytest
import ray

from cluster import connect as connect_module
from cluster.connect import connect, disconnect, local_raylet_running
from cluster.errors import ClusterUnreachable


def fake_gcs() -> tuple[socket.socket, threading.Thread]:
    """A server that answers the HTTP/2 preface with a SETTINGS frame, as a gRPC server does."""
    server = socket.create_server(("127.0.0.1", 0))

    def answer() -> None:
        conn, _ = server.accept()
        with conn:
            conn.recv(1024)
            conn.sendall(struct.pack(">I", 0)[1:] + bytes([0x4, 0, 0, 0, 0, 0]))

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    return server, thread


def test_joining_without_a_local_ray_node_fails_at_once_with_what_to_do(monkeypatch):
    if ray.is_initialized():
        disconnect()
    monkeypatch.setattr(connect_module, "local_raylet_running", lambda: False)
    server, thread = fake_gcs()
    address = f"127.0.0.1:{server.getsockname()[1]}"
    with server, pytest.raises(ClusterUnreachable, match="no Ray node runs on this machine"):
        connect(address)
    thread.join(5)
    assert not ray.is_initialized()  # Ray was never asked


def test_the_raylet_check_sees_a_running_node():
    started = not ray.is_initialized()
    connection = connect(num_cpus=1)
    try:
        assert local_raylet_running()
    finally:
        if started and connection.started:
            disconnect()


def test_the_embedded_ray_listens_on_the_loopback_interface_only():
    if ray.is_initialized():
        disconnect()
    connection = connect(num_cpus=1)
    try:
        assert connection.started
        assert connection.address.startswith("127.0.0.1:")
        assert [n["NodeManagerAddress"] for n in ray.nodes()] == ["127.0.0.1"]
        me = psutil.Process()
        ours = {p.pid for p in [me, *me.children(recursive=True)]}
        listening = {
            (c.laddr.ip, c.laddr.port)
            for c in psutil.net_connections("inet")
            if c.status == psutil.CONN_LISTEN and c.pid in ours
        }
        assert listening  # the GCS and the raylet at least
        assert all(ipaddress.ip_address(ip).is_loopback or ip == "::ffff:127.0.0.1"
                   for ip, _ in listening), listening  # fmt: skip
    finally:
        disconnect()
