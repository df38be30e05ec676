"""The incident PKI in a few commands (`firetrack certs ...`), `serve --tls` as a process, and the
demo still one command without certificates (issue 19)."""
from __future__ import annotations

import ipaddress
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import NameOID
from typer.testing import CliRunner

from client.cli import app
from service.protocol import wire
from service.protocol.access import check_password, load_roster
from service.protocol.tls import TlsConfigError, TlsIdentity
from tests.security_util import bare_tls_client, tls_client, walking_frames
from tests.zenoh_util import free_port

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    res = CliRunner().invoke(app, list(args))
    return res.exit_code, res.output


def _mode(p: Path) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def test_certs_init_issue_revoke_list_and_router_config(tmp_path):
    d = tmp_path / "pki"
    assert _run("certs", "init", "--dir", str(d), "--incident", "fire-42")[0] == 0
    assert _mode(d / "ca.key") == 0o600 and _mode(d / "roster.json") == 0o600
    code, out = _run("certs", "init", "--dir", str(d), "--incident", "fire-42")
    assert code == 2 and "holds an incident CA already" in out
    for role, name, extra in (("service", "svc", ["--san", "10.0.0.2", "--san", "cmd.fire.local"]),
                              ("wearable", "ff1", []), ("operator", "alice", [])):
        code, out = _run("certs", "issue", "--dir", str(d), "--role", role, "--name", name, *extra)
        assert code == 0, out
        assert _mode(d / name / "key.pem") == 0o600
    password = out.split("console password of alice: ")[1].split()[0]
    assert _mode(d / "alice" / "alice.p12") == 0o600
    cert = x509.load_pem_x509_certificate((d / "svc" / "cert.pem").read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "svc"
    assert cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)[0].value == "service"
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert ipaddress.ip_address("10.0.0.2") in san.get_values_for_type(x509.IPAddress)
    assert "cmd.fire.local" in san.get_values_for_type(x509.DNSName)
    ca = x509.load_pem_x509_certificate((d / "ca.crt").read_bytes())
    cert.verify_directly_issued_by(ca)
    ff1 = TlsIdentity.load(d / "ff1")
    assert (ff1.name, ff1.role, ff1.incident) == ("ff1", "wearable", "fire-42")
    roster = load_roster(d / "roster.json")
    assert check_password(password, roster.identities["alice"].password)
    assert not check_password(password + "x", roster.identities["alice"].password)
    assert roster.identities["ff1"].serial == format(
        x509.load_pem_x509_certificate((d / "ff1" / "cert.pem").read_bytes()).serial_number, "x")

    code, out = _run("certs", "issue", "--dir", str(d), "--role", "pilot", "--name", "x")
    assert code == 2 and "--role 'pilot'" in out
    assert _run("certs", "issue", "--dir", str(d), "--role", "operator", "--name", "ff1")[0] == 2  # one name, one role
    assert _run("certs", "revoke", "--dir", str(d), "--name", "ff1")[0] == 0
    code, out = _run("certs", "issue", "--dir", str(d), "--role", "wearable", "--name", "ff1")
    assert code == 2 and "never issued again" in out
    code, out = _run("certs", "list", "--dir", str(d))
    assert code == 0 and "REVOKED" in out and "alice" in out

    assert _run("certs", "issue", "--dir", str(d), "--role", "router", "--name", "zenohd")[0] == 0
    cfg = tmp_path / "zenohd.json5"
    code, out = _run("certs", "router-config", "--dir", str(d), "--tls", str(d / "zenohd"), "--out", str(cfg))
    assert code == 0, out
    text = cfg.read_text()
    zenoh.Config.from_json5(text)
    acl = json.loads("\n".join(x for x in text.splitlines() if not x.startswith("//")))["access_control"]
    names = {n for subject in acl["subjects"] for n in subject.get("cert_common_names", [])}
    assert names == {"svc", "alice"}  # ff1 is revoked: no rules; the router needs none for itself
    code, out = _run("certs", "router-config", "--dir", str(d), "--tls", str(d / "zenohd"), "--listen", "tcp/0.0.0.0:7447")
    assert code == 2 and "plain TCP is refused" in out

    os.chmod(d / "svc" / "key.pem", 0o644)  # a key others can read is refused, as ssh does
    with pytest.raises(TlsConfigError, match="readable by others"):
        TlsIdentity.load(d / "svc")


def _pki(tmp_path) -> Path:
    d = tmp_path / "pki"
    for args in (("init", "--incident", "demo"), ("issue", "--role", "service", "--name", "svc"),
                 ("issue", "--role", "wearable", "--name", "ff1")):
        code, out = _run("certs", args[0], "--dir", str(d), *args[1:])
        assert code == 0, out
    return d


def _wait_for_line(proc, text, timeout=60.0):
    deadline, seen = time.monotonic() + timeout, []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line and proc.poll() is not None:
            break
        seen.append(line)
        if text in line:
            return line
    raise AssertionError(f"{text!r} not printed; got {''.join(seen)}")


def test_serve_with_tls_takes_certified_wearables_and_refuses_the_rest(tmp_path):
    d = _pki(tmp_path)
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "client.entry", "serve", "--no-console", "--tls", str(d / "svc"),
                             "--listen", endpoint], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=ROOT)
    try:
        line = _wait_for_line(proc, "serving incident demo")
        assert "as svc, mutual TLS" in line
        with pytest.raises(zenoh.ZError):
            bare_tls_client(endpoint, d / "ca.crt").close()
        cl = tls_client(endpoint, TlsIdentity.load(d / "ff1"))
        statuses = []
        cl.declare_subscriber(wire.key_all("demo", "status"), lambda s: statuses.append(1))  # refused: a wearable
        for b in walking_frames("ff1", 4.0):
            cl.put(wire.key("demo", "ff1", "imu"), wire.encode(b))
        time.sleep(1.5)
        assert statuses == []
        cl.close()
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0, rest
        assert "stopped; 1 responder(s), 40 frames processed" in rest
    finally:
        if proc.poll() is None:
            proc.kill()


def test_tls_commands_refuse_plain_tcp_and_a_foreign_identity(tmp_path):
    d = _pki(tmp_path)
    code, out = _run("serve", "--no-console", "--tls", str(d / "svc"), "--listen", "tcp/127.0.0.1:7999", "--seconds", "1")
    assert code == 1 and "plain TCP is refused" in out
    code, out = _run("serve", "--no-console", "--tls", str(d / "ff1"), "--seconds", "1")
    assert code == 2 and "wearable certificate" in out
    code, out = _run("wearable", "--tls", str(d / "ff1"), "--responder", "ff2", "--replay", "x.txt")
    assert code == 2 and "'ff1''s" in out
    code, out = _run("console", "--tls", str(d / "ff1"))
    assert code == 2 and "console" in out


def test_the_demo_runs_with_one_command_without_certificates_and_says_it_is_insecure():
    port, web = free_port(), free_port()
    proc = subprocess.run([sys.executable, "-m", "client.entry", "demo", "--seconds", "4", "--port", str(web),
                           "--listen", f"tcp/127.0.0.1:{port}"], capture_output=True, text=True, timeout=180, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert "INSECURE" in proc.stderr and "demo over" in proc.stdout
