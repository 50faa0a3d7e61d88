"""Stalled request bodies are answered 408 and closed (NCS_BODY_TIMEOUT); bodies that keep arriving are served;
names and units with control characters are refused like a label (issue 33, item 6). Real server, raw sockets."""

from __future__ import annotations

import json
import socket
import time

import pytest

from app.examples import PAPER_PLANT

from .conftest import assert_problem, running_client

BODY = json.dumps({"plant": PAPER_PLANT, "n_drop": 3}).encode()


def _request(port: int, body: bytes, declared: int) -> bytes:
    head = (f"POST /v1/designs HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {declared}\r\n\r\n").encode()
    return head + body


def _read_all(sock: socket.socket) -> bytes:
    out = b""
    while True:
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            break
        if not chunk:
            break
        out += chunk
    return out


def test_a_stalled_body_gets_408_and_a_slow_one_is_served(db_url, start_server):
    server = start_server(db_url, NCS_WORKERS=1, NCS_BODY_TIMEOUT=2)
    # 9 of the declared 1,000 bytes, then silence: before, the connection stayed open for ever.
    stalled = [socket.create_connection(("127.0.0.1", server.port), timeout=60) for _ in range(20)]
    for s in stalled:
        s.sendall(_request(server.port, b'{"plant":', 1000))
    for s in stalled:
        answer = _read_all(s)  # the server closes the connection after its answer
        s.close()
        head, _, body = answer.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 408"), answer[:300]
        assert b"application/problem+json" in head and b"NCS_BODY_TIMEOUT" in body, answer[:600]
    # A body that keeps arriving, in pieces with pauses shorter than the limit, is served.
    with socket.create_connection(("127.0.0.1", server.port), timeout=60) as s:
        s.sendall(_request(server.port, b"", len(BODY)))
        for i in range(0, len(BODY), 40):
            s.sendall(BODY[i:i + 40])
            time.sleep(0.2)
        s.shutdown(socket.SHUT_WR)
        answer = _read_all(s)
    assert answer.startswith(b"HTTP/1.1 202"), answer[:300]
    assert server.proc.poll() is None


@pytest.mark.parametrize("field,value", [
    ("state_names", ["x\x00", "v"]), ("state_names", ["x", "v\x1b[31m"]), ("units", {"x": "m\x07"}),
    ("mode_names", ["a\x0b"]),
])
def test_names_with_control_characters_are_refused_naming_the_field(db_url, field, value):
    plant = {"kind": "continuous", "A": [[[0.0, 1.0], [0.0, 0.0]]], "B": [[[0.0], [1.0]]], "sampling_period": 0.1,
             "state_names": ["x", "v"]}
    plant[field] = value
    with running_client(db_url, run_dispatcher=False) as client:
        resp = client.post("/v1/designs", json={"plant": plant, "n_drop": 2})
        problem = assert_problem(resp, 422)
        assert any(f"/plant/{field}" in e["pointer"] for e in problem["errors"]), problem


def test_the_library_refuses_control_characters_in_names_too():
    from solver import InvalidInput, PlantFamily

    F, G = [[[1.0, 0.1], [0.0, 1.0]]], [[[0.0], [0.1]]]
    with pytest.raises(InvalidInput, match=r"state_names\[1\] contains a control character"):
        PlantFamily(F, G, state_names=["x", "v\x00"])
    with pytest.raises(InvalidInput, match="control character"):
        PlantFamily(F, G, state_names=["x", "v"], units={"x": "m\n"})


def test_malformed_framing_gets_the_documented_plain_400(db_url, start_server):
    """docs/service.md: the HTTP server refuses broken framing before the application (no problem+json there)."""
    server = start_server(db_url, NCS_WORKERS=1)
    for raw in (b"GARBAGE\r\n\r\n", b"POST /v1/designs HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n"):
        with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
            s.sendall(raw)
            answer = _read_all(s)
        assert answer.startswith(b"HTTP/1.1 400") and b"text/plain" in answer, answer[:300]
        assert answer.endswith(b"Invalid HTTP request received."), answer[-100:]
    assert server.proc.poll() is None
