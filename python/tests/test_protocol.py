"""A RobotServer client written from docs/protocol.md alone, with Python's own socket and ssl
modules (OpenSSL) and a certificate made by the `openssl` command: no twinbots code on the
client's side. Frames are a 4-byte little-endian length and UTF-8 JSON."""

import json
import os
import shutil
import socket
import ssl
import struct
import subprocess

import pytest


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


def send(sock, message):
    payload = json.dumps(message).encode()
    sock.sendall(struct.pack("<I", len(payload)) + payload)


def receive(sock):
    def exactly(n):
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            assert chunk, "the server closed the connection"
            data += chunk
        return data

    (length,) = struct.unpack("<I", exactly(4))
    return json.loads(exactly(length))


@pytest.fixture
def tls_server(tmp_path):
    """`twinbots serve cartpole` with TLS and a token, on a self-signed certificate for
    127.0.0.1 (not marked as a CA, as docs/protocol.md says); yields (address, certificate)."""
    if not shutil.which("openssl"):
        pytest.skip("no openssl command")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-keyout", str(key), "-out", str(cert), "-days", "2", "-subj", "/CN=twinbots test",
         "-addext", "subjectAltName=IP:127.0.0.1", "-addext", "basicConstraints=critical,CA:FALSE"],
        check=True, capture_output=True,
    )
    server = subprocess.Popen(
        [twinbots_bin(), "serve", "cartpole", "--listen", "127.0.0.1:0", "--robots", "1", "--timesteps", "100000",
         "--token", "s3cret", "--tls-cert", str(cert), "--tls-key", str(key), "--out", str(tmp_path / "run")],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    try:
        line = server.stdout.readline()
        assert line.startswith("listening on "), line
        host, port = line.split()[-1].rsplit(":", 1)
        yield (host, int(port)), cert
    finally:
        server.kill()
        server.wait()


def robot_hello(token):
    robots = subprocess.run([twinbots_bin(), "robots", "--json"], capture_output=True, check=True, text=True)
    spaces = json.loads(robots.stdout)
    task = next(r for r in spaces["robots"] if r["name"] == "cartpole")["tasks"][0]
    return {"type": "hello", "version": 2, "robot": "cartpole", "observation_space": task["observation_space"],
            "action_space": task["action_space"], "token": token}


def test_an_openssl_client_talks_to_a_tls_server(tls_server):
    addr, cert = tls_server
    context = ssl.create_default_context(cafile=str(cert))
    with socket.create_connection(addr, timeout=10) as raw, context.wrap_socket(raw, server_hostname=addr[0]) as sock:
        send(sock, robot_hello("s3cret"))
        welcome = receive(sock)
        assert welcome["type"] == "welcome" and welcome["version"] == 2, welcome
        high = welcome["task"]["observation_plausible"]["Box"]["high"]
        assert high == [5.0, 20.0, pytest.approx(3.14159265, rel=1e-6), 100.0]
        assert welcome["task"]["control_period_s"] == 0.032, welcome["task"]
        send(sock, {"type": "start", "obs": [0.0, 0.0, 0.01, 0.0]})
        action = receive(sock)
        assert action["type"] == "action" and action["action"][0] in (0.0, 1.0), action
        # A faulty reading: refused, named, and the connection goes on.
        send(sock, {"type": "step", "obs": [0.0, 0.0, 1e6, 0.0], "reward": 1.0,
                    "terminated": False, "truncated": False})
        refused = receive(sock)
        assert (refused["type"] == "error" and refused["code"] == "observation_out_of_range"
                and not refused["fatal"]), refused
        assert "pole_angle" in refused["message"]
        send(sock, {"type": "step", "obs": [0.0, 0.0, 0.02, 0.0], "reward": 1.0,
                    "terminated": False, "truncated": False})
        assert receive(sock)["type"] == "action"
        # `ended_by` names one of the task's termination terms, and only on a terminal step.
        terms = welcome["task"]["termination_terms"]
        assert "pole_fallen" in terms, welcome["task"]
        send(sock, {"type": "step", "obs": [0.0, 0.0, 0.3, 0.0], "reward": 1.0,
                    "terminated": True, "truncated": False, "ended_by": "tipped_over"})
        refused = receive(sock)
        assert refused["type"] == "error" and refused["code"] == "unknown_termination" and not refused["fatal"], refused
        assert "pole_fallen" in refused["message"], refused
        send(sock, {"type": "step", "obs": [0.0, 0.0, 0.3, 0.0], "reward": 1.0,
                    "terminated": True, "truncated": False, "ended_by": "pole_fallen"})
        assert receive(sock)["type"] == "ack"
        send(sock, {"type": "bye"})


def test_a_client_that_does_not_trust_the_certificate_or_speaks_plain_tcp_gets_nothing(tls_server, tmp_path):
    addr, _ = tls_server
    # The system's authorities do not know this self-signed certificate.
    with socket.create_connection(addr, timeout=10) as raw:
        with pytest.raises(ssl.SSLCertVerificationError):
            ssl.create_default_context().wrap_socket(raw, server_hostname=addr[0])
    # Plain TCP: the hello is not a TLS handshake; the server answers with a TLS alert record
    # (content type 21), never a frame of the protocol, and closes.
    with socket.create_connection(addr, timeout=10) as sock:
        send(sock, robot_hello("s3cret"))
        reply = b""
        while chunk := sock.recv(4096):
            reply += chunk
        assert reply[:1] == b"\x15" and b"welcome" not in reply, reply
