"""Zenoh session namespaces isolate runs that share a mesh (interfaces.zenoh_transport, bof-sitl's plain runs).

Zenoh itself is the reference: sessions on one listener, each with or without a namespace; what a
subscriber receives is what zenoh delivered.
"""

from __future__ import annotations

import socket
import threading
import time

import pytest

from interfaces.zenoh_transport import LinkError, check_namespace, open_session, zenoh_config
from studies.processes import free_port, poll_until


def test_a_session_hears_its_own_namespace_and_never_another():
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    hub = open_session(zenoh_config(listen=[endpoint], namespace="run-a"))
    other = open_session(zenoh_config(connect=[endpoint], namespace="run-b"))
    bare = open_session(zenoh_config(connect=[endpoint]))
    same = open_session(zenoh_config(connect=[endpoint], namespace="run-a"))
    got: list[str] = []
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            got.append(sample.payload.to_bytes().decode())

    try:
        subscriber = hub.declare_subscriber("bof/**", on_sample)
        time.sleep(0.5)  # the declarations reach every peer
        other.put("bof/companion/companion-1/command", "from run-b")
        bare.put("bof/companion/companion-1/command", "without a namespace")
        same.put("bof/companion/companion-1/command", "from run-a")  # sent last: zenoh delivers in order per link
        poll_until(lambda: "from run-a" in got, 5.0, 0.02)
        time.sleep(0.3)
        assert got == ["from run-a"]
        subscriber.undeclare()
    finally:
        for session in (same, bare, other, hub):
            session.close()


@pytest.mark.parametrize("bad", ["", "a//b", "/a", "a/", "has space", "star/*", "x" * 65, "/".join(["a"] * 9)])
def test_a_malformed_namespace_is_a_link_error(bad):
    with pytest.raises(LinkError):
        check_namespace(bad)
    with pytest.raises(LinkError):
        zenoh_config(namespace=bad)


def test_bof_sitl_style_namespaces_are_accepted():
    assert check_namespace("bof-sitl-0a1b2c3d") == "bof-sitl-0a1b2c3d"
    assert check_namespace("lab.3/run_7") == "lab.3/run_7"
