"""``firetrack certs``: the incident's PKI and roster in a few commands.

::

    firetrack certs init --dir pki --incident fire-42            # the incident CA and an empty roster
    firetrack certs issue --dir pki --role service --name svc --san 10.0.0.2
    firetrack certs issue --dir pki --role wearable --name ff1   # CN = the responder id
    firetrack certs issue --dir pki --role operator --name alice # prints alice's console password once
    firetrack certs reserve --dir pki --role wearable --name ff21 --name ff22
    firetrack certs revoke --dir pki --name ff3
    firetrack certs list --dir pki
    firetrack certs router-config --dir pki --tls pki/router --listen tls/0.0.0.0:7447 > zenohd.json5

Every process then takes ``--tls pki/NAME`` (see :mod:`service.protocol.tls`).
"""
from __future__ import annotations

from pathlib import Path

import typer

from service.protocol.terminal import fail, out

app = typer.Typer(help="The incident PKI: a CA, one certificate per identity, the roster the router's rules come from.",
                  no_args_is_help=True)

DIR_OPTION = typer.Option(Path("pki"), "--dir", help="the incident's PKI directory")


def _pki():
    from service.protocol import pki

    return pki


@app.command("init")
def init_command(
    directory: Path = DIR_OPTION,
    incident: str = typer.Option(..., "--incident", help="the incident id (the keys' firetrack/{incident}/...)"),
    hours: float = typer.Option(24.0, "--hours", help="validity of the CA, h (no certificate outlives it)"),
    force: bool = typer.Option(False, "--force", help="replace an existing CA (every certificate it issued stops working)"),
):
    """Create the incident CA (ca.crt, ca.key 0600) and an empty roster."""
    pki = _pki()
    try:
        ca = pki.init_ca(directory, incident, hours, force)
    except (pki.PkiError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(2)
    out.print(f"incident CA for {incident!r}: {ca} (its key {directory / pki.CA_KEY_FILE} stays on this machine)")


@app.command("issue")
def issue_command(
    directory: Path = DIR_OPTION,
    role: str = typer.Option(..., "--role", help="service | console | operator | viewer | wearable | anchor | simulator | gateway | router"),
    name: str = typer.Option(..., "--name", help="the identity: a wearable's responder id, an operator's login name"),
    san: list[str] = typer.Option(None, "--san", help="an address it is reached at (router, service, console); repeat"),
    hours: float = typer.Option(None, "--hours", help="validity, h (default 24, never beyond the CA)"),
    password_file: Path = typer.Option(None, "--password-file", help="operators/viewers: read the console password "
                                                                     "from this file instead of making one up"),
):
    """Issue NAME a certificate of ROLE (CN = NAME) into DIR/NAME, and record it in the roster."""
    pki = _pki()
    password = password_file.read_text().strip() if password_file else None
    try:
        issued = pki.issue(directory, role, name, list(san or []), hours, password=password)
    except (pki.PkiError, ValueError, OSError) as e:
        fail(str(e))
        raise typer.Exit(2)
    out.print(f"{issued.role} {issued.name}: {issued.dir} (serial {issued.serial}, valid until {issued.not_after}); "
              f"use it with --tls {issued.dir}", highlight=False)
    if issued.password is not None:
        out.print(f"console password of {issued.name}: {issued.password}   (shown once; also unlocks "
                  f"{issued.dir / (issued.name + '.p12')} for a browser)", highlight=False)


@app.command("reserve")
def reserve_command(
    directory: Path = DIR_OPTION,
    role: str = typer.Option(..., "--role", help="the role the names will have"),
    name: list[str] = typer.Option(..., "--name", help="a name to reserve; repeat"),
):
    """Add names to the roster before their certificates exist, so the router's rules cover them."""
    pki = _pki()
    try:
        pki.reserve(directory, role, list(name))
    except (pki.PkiError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(2)
    out.print(f"reserved {len(name)} {role} name(s): {', '.join(name)} (regenerate the router's config and restart it "
              "if it is running)", highlight=False)


@app.command("revoke")
def revoke_command(directory: Path = DIR_OPTION, name: str = typer.Option(..., "--name", help="the identity to revoke")):
    """Revoke NAME: the service refuses it within a second; the router drops it at its next restart."""
    pki = _pki()
    try:
        pki.revoke(directory, name)
    except (pki.PkiError, ValueError) as e:
        fail(str(e))
        raise typer.Exit(2)
    out.print(f"{name} revoked: the service refuses it from now on; regenerate the router's config "
              "(`firetrack certs router-config`) and restart the router to drop it there too", highlight=False)


@app.command("list")
def list_command(directory: Path = DIR_OPTION):
    """The roster: every identity, its role, certificate and state."""
    from service.protocol.access import RosterError, load_roster

    try:
        roster = load_roster(directory / "roster.json")
    except RosterError as e:
        fail(str(e))
        raise typer.Exit(2)
    out.print(f"incident {roster.incident}: {len(roster.identities)} identities", highlight=False)
    for name, i in sorted(roster.identities.items(), key=lambda kv: (kv[1].role, kv[0])):
        state = "REVOKED " + (i.revoked_at or "") if i.revoked else ("reserved" if i.serial is None else
                                                                    f"serial {i.serial} until {i.not_after}")
        out.print(f"  {i.role:9s} {name:24s} {state}", highlight=False)


@app.command("router-config")
def router_config_command(
    directory: Path = DIR_OPTION,
    tls: Path = typer.Option(..., "--tls", help="the router's own identity directory (role router or service)"),
    listen: list[str] = typer.Option(None, "--listen", help="endpoint(s), default tls/0.0.0.0:7447"),
    out_file: Path = typer.Option(None, "--out", help="write here (default: standard output)"),
):
    """A zenohd configuration: mutual TLS only, and access control generated from the roster."""
    from service.protocol.access import RosterError, load_roster, router_config_json5
    from service.protocol.tls import TlsConfigError, TlsIdentity, check_endpoints

    try:
        ident = TlsIdentity.load(tls).require_role("router", "service", what="a router")
        eps = check_endpoints(list(listen or ["tls/0.0.0.0:7447"]), ident, "--listen")
        text = router_config_json5(load_roster(directory / "roster.json"), str(ident.dir), eps)
    except (RosterError, TlsConfigError) as e:
        fail(str(e))
        raise typer.Exit(2)
    if out_file is None:
        print(text, end="")
    else:
        out_file.write_text(text)
        out.print(f"zenohd config written to {out_file}: `zenohd -c {out_file}`")
