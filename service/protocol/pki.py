"""The incident's certificate authority: one CA per incident, one certificate per identity.

Made with the ``cryptography`` package (``pip install 'firetrack[service]'``); the devices
that only *use* a certificate (a wearable) never import this module. Layout of the PKI
directory (``firetrack certs init DIR``)::

    DIR/ca.crt        the incident CA certificate (public: every identity trusts it)
    DIR/ca.key        the CA private key, mode 0600: stays on the command laptop
    DIR/roster.json   every identity of the incident (service.protocol.access.Roster), mode 0600
    DIR/NAME/         one directory per identity: what ``--tls DIR/NAME`` reads
                      (service.protocol.tls: ca.crt, cert.pem, key.pem 0600, identity.json),
                      plus NAME.p12 for operators and viewers (a browser imports it)

Keys are ECDSA P-256 (what rustls, zenoh's TLS, and every browser take). The common name is
the identity: a wearable's responder id, an operator's login name. The certificate's
subject alternative names are ``localhost``, ``127.0.0.1``, ``::1`` plus any ``--san`` (the
address a router or a console is reached at; zenoh checks it on connect, browsers too).
Validity is one incident (24 h by default): links close when it ends.
"""
from __future__ import annotations

import datetime as dt
import ipaddress
import json
import os
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.serialization import pkcs12
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from service.protocol.access import Roster, RosterError, load_roster, save_roster
from service.protocol.keys import check_id
from service.protocol.tls import CA_FILE, CERT_FILE, IDENTITY_FILE, KEY_FILE, ROLES, ROSTER_FILE

CA_KEY_FILE = "ca.key"
DEFAULT_VALID_H = 24.0  # h: one incident; links close when the certificate expires
CLOCK_SKEW_S = 300.0  # s: a certificate is valid from this long before it was made (devices' clocks differ)
LOCAL_NAMES = ("localhost", "127.0.0.1", "::1")


class PkiError(ValueError):
    """A PKI directory or a request that cannot be used; the message says what and where."""


def _write(path: Path, data: bytes, private: bool) -> None:
    """Write ``data``; a private key is created with mode 0600 from the first byte."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _now() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)


def _pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _key_pem(key) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def init_ca(directory: str | Path, incident: str, valid_h: float = DEFAULT_VALID_H, force: bool = False) -> Path:
    """Create the incident CA and an empty roster in ``directory``; returns the CA certificate's path."""
    check_id("incident", incident)
    d = Path(directory)
    if (d / CA_KEY_FILE).exists() and not force:
        raise PkiError(f"{d} holds an incident CA already ({CA_KEY_FILE}); use another directory, or --force to "
                       "replace it (every certificate it issued stops working)")
    d.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "firetrack"),
                      x509.NameAttribute(NameOID.COMMON_NAME, f"firetrack incident {incident} CA")])
    now = _now()
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(seconds=CLOCK_SKEW_S))
            .not_valid_after(now + dt.timedelta(hours=valid_h))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write(d / CA_KEY_FILE, _key_pem(key), private=True)
    _write(d / CA_FILE, _pem(cert), private=False)
    save_roster(d / ROSTER_FILE, Roster(incident=incident, ca_serial=format(cert.serial_number, "x")))
    return d / CA_FILE


@dataclass(frozen=True)
class Issued:
    name: str
    role: str
    dir: Path
    serial: str
    not_after: str
    password: str | None = None  # the console password, shown once (operators, viewers)


def _load_ca(d: Path):
    try:
        key = serialization.load_pem_private_key((d / CA_KEY_FILE).read_bytes(), password=None)
        cert = x509.load_pem_x509_certificate((d / CA_FILE).read_bytes())
    except FileNotFoundError as e:
        raise PkiError(f"{d}: no incident CA here ({Path(e.filename).name} missing); `firetrack certs init {d}` "
                       "first") from None
    except ValueError as e:
        raise PkiError(f"{d}: the CA files cannot be read: {e}") from None
    return key, cert


def _san(names) -> x509.SubjectAlternativeName:
    out: list[x509.GeneralName] = []
    for n in dict.fromkeys(names):  # keep order, no duplicates
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(n)))
        except ValueError:
            out.append(x509.DNSName(n))
    return x509.SubjectAlternativeName(out)


def issue(directory: str | Path, role: str, name: str, sans: list[str] = (), valid_h: float | None = None,
          password: str | None = None, with_password: bool | None = None) -> Issued:
    """Issue ``name`` a certificate of ``role`` signed by the incident CA in ``directory`` and
    write its identity directory ``directory/name``; the roster records it. Operators and
    viewers also get a console password (given, or made up and returned once) and a PKCS#12
    bundle for a browser."""
    if role not in ROLES:
        raise PkiError(f"--role {role!r}: one of {', '.join(ROLES)}")
    try:
        check_id("identity", name)
    except ValueError as e:
        raise PkiError(str(e)) from None
    d = Path(directory)
    ca_key, ca_cert = _load_ca(d)
    roster = load_roster(d / ROSTER_FILE)
    try:
        entry = roster.add(name, role)
    except (RosterError, ValueError) as e:
        raise PkiError(str(e)) from None
    now = _now()
    end = now + dt.timedelta(hours=valid_h if valid_h is not None else DEFAULT_VALID_H)
    end = min(end, ca_cert.not_valid_after_utc)  # never beyond the CA
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "firetrack"),
                         x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, role),
                         x509.NameAttribute(NameOID.COMMON_NAME, name)])
    builder = (x509.CertificateBuilder().subject_name(subject).issuer_name(ca_cert.subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - dt.timedelta(seconds=CLOCK_SKEW_S)).not_valid_after(end)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=True, key_encipherment=False, content_commitment=False,
                                            data_encipherment=False, key_agreement=True, key_cert_sign=False,
                                            crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
               .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                     ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
               .add_extension(_san([*LOCAL_NAMES, *sans]), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False))
    cert = builder.sign(ca_key, hashes.SHA256())
    out = d / name
    _write(out / KEY_FILE, _key_pem(key), private=True)
    _write(out / CERT_FILE, _pem(cert), private=False)
    _write(out / CA_FILE, _pem(ca_cert), private=False)
    serial = format(cert.serial_number, "x")
    info = {"name": name, "role": role, "incident": roster.incident, "serial": serial,
            "not_after": end.isoformat(timespec="seconds")}
    _write(out / IDENTITY_FILE, (json.dumps(info, indent=2) + "\n").encode(), private=False)
    if with_password is None:
        with_password = role in ("operator", "viewer")
    shown = None
    if with_password:
        from service.protocol.access import hash_password, new_password

        shown = password or new_password()
        entry.password = hash_password(shown)
        p12 = pkcs12.serialize_key_and_certificates(name.encode(), key, cert, [ca_cert],
                                                    serialization.BestAvailableEncryption(shown.encode()))
        _write(out / f"{name}.p12", p12, private=True)
    entry.serial, entry.not_after = serial, info["not_after"]
    save_roster(d / ROSTER_FILE, roster)
    return Issued(name, role, out, serial, info["not_after"], shown)


def reserve(directory: str | Path, role: str, names: list[str]) -> Roster:
    """Put ``names`` in the roster without a certificate yet, so a router started now already
    has their rules (a responder joining mid-incident)."""
    d = Path(directory)
    roster = load_roster(d / ROSTER_FILE)
    for n in names:
        try:
            roster.add(n, role)
        except (RosterError, ValueError) as e:
            raise PkiError(str(e)) from None
    save_roster(d / ROSTER_FILE, roster)
    return roster


def revoke(directory: str | Path, name: str) -> Roster:
    """Mark ``name`` revoked in the roster: the service refuses it from its next look at the
    roster (about a second), the router at its next restart; its files are kept for the record."""
    d = Path(directory)
    roster = load_roster(d / ROSTER_FILE)
    ident = roster.identities.get(name)
    if ident is None:
        raise PkiError(f"{name!r} is not in the roster of incident {roster.incident!r}")
    if not ident.revoked:
        ident.revoked, ident.revoked_at = True, _now().isoformat(timespec="seconds")
        ident.password = None
    save_roster(d / ROSTER_FILE, roster)
    return roster


def certificate_common_name(pem_or_der: bytes) -> str | None:
    """The common name of a certificate (PEM or DER), or None."""
    try:
        cert = (x509.load_pem_x509_certificate(pem_or_der) if pem_or_der.lstrip().startswith(b"-----")
                else x509.load_der_x509_certificate(pem_or_der))
        attrs = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        return str(attrs[0].value) if attrs else None
    except ValueError:
        return None
