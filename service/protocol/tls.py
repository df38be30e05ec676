"""A TLS identity as a process uses it: the ``--tls DIR`` of every firetrack command.

``firetrack certs issue --role ROLE --name NAME`` writes one directory per identity
(:mod:`service.protocol.pki`)::

    DIR/ca.crt          the incident CA's certificate (whom to trust)
    DIR/cert.pem        this identity's certificate, common name = NAME
    DIR/key.pem         its private key (mode 0600)
    DIR/identity.json   {"name", "role", "incident", "serial", "not_after"}: what the certificate says,
                        readable without a crypto library (a wearable needs none)

Given ``--tls DIR``, a command opens its zenoh session with mutual TLS (router: listener
certificate + client certificates required; client: its certificate + the CA), and only
``tls/`` links: plain TCP is refused both ways (``transport/link/protocols``). Links close
when a certificate expires (``close_link_on_expiration``), which bounds how long a revoked
certificate can stay connected (see :mod:`service.protocol.access`).
"""
from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path

ROLES = ("service", "router", "console", "operator", "viewer", "wearable", "anchor", "simulator", "gateway")
CA_FILE = "ca.crt"
CERT_FILE = "cert.pem"
KEY_FILE = "key.pem"
IDENTITY_FILE = "identity.json"
ROSTER_FILE = "roster.json"


class TlsConfigError(ValueError):
    """A ``--tls`` directory that cannot be used: says which file and what is wrong."""


@dataclass(frozen=True)
class TlsIdentity:
    """The files of one identity (see the module docstring) and what its certificate says."""

    dir: Path
    name: str
    role: str
    incident: str | None = None

    @property
    def ca(self) -> Path:
        return self.dir / CA_FILE

    @property
    def cert(self) -> Path:
        return self.dir / CERT_FILE

    @property
    def key(self) -> Path:
        return self.dir / KEY_FILE

    @classmethod
    def load(cls, directory: str | Path) -> TlsIdentity:
        """Check that ``directory`` holds a usable identity; :class:`TlsConfigError` says what is
        missing. A private key that others may read is refused, as ssh refuses one."""
        d = Path(directory).expanduser()
        if not d.is_dir():
            raise TlsConfigError(f"--tls {d}: not a directory (make one with `firetrack certs issue`)")
        for f in (CA_FILE, CERT_FILE, KEY_FILE, IDENTITY_FILE):
            if not (d / f).is_file():
                raise TlsConfigError(f"--tls {d}: {f} is missing; a directory written by `firetrack certs issue` "
                                     f"holds {CA_FILE}, {CERT_FILE}, {KEY_FILE} and {IDENTITY_FILE}")
        mode = stat.S_IMODE(os.stat(d / KEY_FILE).st_mode)
        if mode & 0o077:
            raise TlsConfigError(f"--tls {d}: {KEY_FILE} is readable by others (mode {mode:04o}); "
                                 f"`chmod 600 {d / KEY_FILE}`")
        try:
            info = json.loads((d / IDENTITY_FILE).read_text())
            name, role = str(info["name"]), str(info["role"])
        except (ValueError, KeyError, TypeError) as e:
            raise TlsConfigError(f"--tls {d}: {IDENTITY_FILE} is not an identity file ({e})") from None
        if role not in ROLES:
            raise TlsConfigError(f"--tls {d}: role {role!r} in {IDENTITY_FILE} is not one of {', '.join(ROLES)}")
        return cls(d.resolve(), name, role, info.get("incident"))

    def require_role(self, *roles: str, what: str) -> TlsIdentity:
        """This identity, or :class:`TlsConfigError` when its role cannot do ``what``."""
        if self.role not in roles:
            raise TlsConfigError(f"--tls {self.dir}: {self.name!r} is a {self.role} certificate; {what} needs "
                                 f"a {' or '.join(roles)} certificate (the router's access control would refuse it)")
        return self

    def roster_path(self) -> Path | None:
        """The incident's roster beside this identity (``DIR/../roster.json`` as ``certs issue``
        lays it out, or ``DIR/roster.json``), when there is one."""
        for p in (self.dir.parent / ROSTER_FILE, self.dir / ROSTER_FILE):
            if p.is_file():
                return p
        return None

    def zenoh_tls(self, listen: bool) -> dict:
        """The ``transport/link/tls`` section: mutual TLS, certificate checked against the CA,
        the server's name checked against the endpoint, links closed when a certificate expires."""
        own = ({"listen_certificate": str(self.cert), "listen_private_key": str(self.key)} if listen else {})
        return {
            "root_ca_certificate": str(self.ca),
            **own,
            "connect_certificate": str(self.cert),
            "connect_private_key": str(self.key),
            "enable_mtls": True,
            "verify_name_on_connect": True,
            "close_link_on_expiration": True,
        }


def check_endpoints(endpoints: list[str], tls: TlsIdentity | None, option: str) -> list[str]:
    """With TLS, every endpoint must be ``tls/...``: plain TCP is refused, not silently upgraded."""
    if tls is None:
        return endpoints
    plain = [e for e in endpoints if not e.startswith("tls/")]
    if plain:
        raise TlsConfigError(f"{option} {', '.join(plain)}: with --tls only tls/HOST:PORT endpoints are used "
                             f"(plain TCP is refused); e.g. {plain[0].replace(plain[0].split('/', 1)[0], 'tls', 1)}")
    return endpoints
