"""Zenoh sessions for every process: loopback-only configuration, opening, publishers.

Topology (measured on loopback, eclipse-zenoh 1.10, multicast scouting off)
--------------------------------------------------------------------------
The plant (A) is a peer that listens on ``tcp/127.0.0.1:PORT``. Every other process
(target B, companion C, ground station D) is a peer that connects to A **and listens
on** ``tcp/127.0.0.1:0`` (a loopback port the kernel picks)::

    A: zenoh_config(listen=["tcp/127.0.0.1:7447"])
    B, C, D: zenoh_config(connect=["tcp/127.0.0.1:7447"])   # listen defaults to tcp/127.0.0.1:0

Gossip scouting (on by default) tells B and C about each other through A and they
open a direct link, so C receives B's publications in any start order, even when B
and C start seconds before A, and across a restart of A. What did not work:

* peers that connect to A but listen nowhere: C never receives B. A peer forwards
  nothing between two other peers, and **neither does A in router mode** (peers
  assume they form a full mesh). One side of each pair listening is enough.
* zenoh's own peer default: listen on ``tcp/[::]:0``, i.e. **every interface**. So
  `zenoh_config` always sets the listen endpoints and refuses non-loopback ones
  unless ``allow_remote_listen=True``.

Client mode to the peer A also works (A routes for its clients, also when B and C
form a peer mesh; a client has no listener at all), but a client's `zenoh.open` fails at once if A is not up yet (unless
``connect/timeout_ms = -1``, which blocks until it is), so the peer mesh is the
default. Client mode suits a ground station on another machine: gossip hands out the
peers' loopback addresses, which it could not reach.

"""

from __future__ import annotations

import ipaddress
import json
import re
from collections.abc import Iterable
from typing import Literal

import zenoh


class LinkError(RuntimeError):
    """The Zenoh session could not be configured or opened."""


#: What an empty `listen` gives a peer: a loopback port the kernel picks, so that gossip can
#: link peers directly (a peer that listens nowhere never hears other non-listening peers).
LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"
_ENDPOINT = re.compile(r"(?P<protocol>[a-z0-9\-]+)/(?P<address>[^?#]+)(?:\?[^#]*)?(?:#.*)?")


def _endpoint_host(endpoint: str) -> str:
    match = _ENDPOINT.fullmatch(endpoint) if isinstance(endpoint, str) else None
    if match is None:
        raise LinkError(f"Zenoh endpoint {endpoint!r}: expected <protocol>/<host>:<port>, e.g. tcp/127.0.0.1:7447")
    address = match["address"]
    if address.startswith("["):
        host, _, rest = address[1:].partition("]")
        port = rest.removeprefix(":")
    else:
        host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or int(port) > 65535:
        raise LinkError(f"Zenoh endpoint {endpoint!r}: expected <protocol>/<host>:<port>, e.g. tcp/127.0.0.1:7447")
    return host


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def zenoh_config(mode: Literal["peer", "client", "router"] = "peer", listen: Iterable[str] = (),
                 connect: Iterable[str] = (), multicast_scouting: bool = False, *,
                 allow_remote_listen: bool = False, overrides: dict[str, str] | None = None) -> zenoh.Config:
    """A Zenoh session configuration (see the module docstring for the topology).

    mode: "peer" (default), "client" (no listener; needs `connect`) or "router".
    listen: endpoints to listen on, e.g. "tcp/127.0.0.1:7447"; empty gives a peer or
    router LOOPBACK_ANY_PORT (zenoh's own default would be every interface). Listening
    on a non-loopback address raises LinkError unless allow_remote_listen.
    connect: endpoints to connect to. multicast_scouting: UDP multicast discovery
    (off: only the explicit endpoints and gossip over them are used).
    overrides: further Zenoh configuration entries, key path -> JSON5 value, applied last
    (e.g. TLS: {"transport/link/tls/root_ca_certificate": '"/etc/bof/ca.pem"'}); dots in
    the key path are accepted for slashes. A listen endpoint set here is checked like
    `listen`.
    """
    listen, connect = list(listen), list(connect)
    if mode not in ("peer", "client", "router"):
        raise LinkError(f"Zenoh mode {mode!r}: expected 'peer', 'client' or 'router'")
    for endpoint in connect:
        _endpoint_host(endpoint)
    for endpoint in listen:
        host = _endpoint_host(endpoint)
        if not allow_remote_listen and not _is_loopback(host):
            raise LinkError(f"Zenoh listen endpoint {endpoint!r} is not loopback; pass allow_remote_listen=True "
                            "to accept connections from other machines")
    if mode == "client":
        if listen:
            raise LinkError("a Zenoh client cannot listen; use mode='peer' or drop the listen endpoints")
        if not connect:
            raise LinkError("a Zenoh client needs a connect endpoint (multicast scouting aside)")
    elif not listen:
        listen = [LOOPBACK_ANY_PORT]
    config = zenoh.Config()
    try:
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("listen/endpoints", json.dumps(listen))
        config.insert_json5("connect/endpoints", json.dumps(connect))
        config.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
        for key, value in (overrides or {}).items():
            path = key.replace(".", "/")
            if path.startswith("listen") and not allow_remote_listen:
                raise LinkError(f"Zenoh override {key!r}: set listen endpoints with `listen`, not an override")
            config.insert_json5(path, value)
    except zenoh.ZError as error:
        raise LinkError(f"invalid Zenoh configuration: {error}") from None
    return config


def open_session(config: zenoh.Config) -> zenoh.Session:
    """Open a Zenoh session; LinkError (saying why) if it cannot be opened, e.g. a port in use."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as error:
        raise LinkError(f"cannot open the Zenoh session: {error}") from None


def publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    """A publisher of JSON payloads on `key`.

    Zenoh's defaults otherwise: reliable, batched, and dropping (never blocking the
    caller) when the link is congested. Not express: on loopback express messages were
    no faster (median 0.4 ms either way) but a burst of 5000 lost 43% of them, and
    bursts of 100 fixes lost some in 5 of 30 trials; batched, none were lost.
    """
    return session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON)
