"""Who may talk to a unit: mutual TLS and Zenoh's access control, by role.

A unit's credentials (``ctrlunit keys init DIR``, :func:`make_keys`) are one certificate
authority and one key and certificate per role, each certificate's common name the role's
name (``central``, ``plant``, ``peripheral-K``, ``viewer``). With ``--keys DIR`` every
link that is not the local socket is TLS with mutual authentication (a peer without a
certificate signed by the unit's authority cannot connect), and each role's session
carries the same access-control policy (:func:`access_control`), default deny:

- only the plant publishes samples to the central;
- only peripheral K publishes its replies (``central/reply/K``);
- only the central publishes into the plant's and the peripherals' inboxes (requests,
  commands, orders);
- the unit's roles say hello and bye to the central;
- every authenticated peer, a viewer included, may subscribe and be sent what the
  central publishes; a viewer may publish nothing.

Zenoh drops a message the policy denies before the role sees it. Before anything starts,
:func:`check_credentials` checks the files of the roles a run uses (they parse, each key
is its certificate's, each certificate is the role's and signed by the authority, and
valid now; no key others can read, no file others can write). What this protects, and
what not, is in docs/faults-and-errors.md (Security).
"""

from __future__ import annotations

import datetime
import ipaddress
import json
from pathlib import Path
from typing import Any

CA_CERT = "ca.pem"
CA_KEY = "ca.key"
VIEWER = "viewer"
MAX_PERIPHERALS = 3
VALID_DAYS = 365


def role_names(peripherals: int = MAX_PERIPHERALS) -> list[str]:
    """The roles a unit's credentials cover: central, plant, peripheral-1..n, viewer."""
    return ["central", "plant", *(f"peripheral-{k}" for k in range(1, peripherals + 1)),
            VIEWER]


def make_keys(directory: str | Path, *, authority: str | Path | None = None,
              peripherals: int = MAX_PERIPHERALS, days: int = VALID_DAYS) -> list[Path]:
    """Write a unit's credentials: ``ca.pem`` and a key and certificate per role
    (:func:`role_names`) into ``directory``, the authority's ``ca.key`` (and a copy of
    ``ca.pem``) into ``authority`` (default: the sibling ``<directory>-authority``). Both
    directories are made 0700, keys 0600, certificates 0644, whatever the umask; no file
    is overwritten (a :class:`FileExistsError` names the first, before anything is
    written). Returns the files written, the authority's two last.

    Uses the ``cryptography`` package: an ECDSA P-256 authority and, per role, a
    certificate for both TLS server and client use whose common name is the role
    (runtime/transport/keygen.py)."""
    from .keygen import write_keys

    return write_keys(directory, role_names(peripherals), authority=authority, days=days,
                      ca_cert=CA_CERT, ca_key=CA_KEY)


def credentials(directory: str | Path, role: str) -> dict[str, str]:
    """The authority's certificate and ``role``'s key and certificate in ``directory``.

    Raises
    ------
    FileNotFoundError
        Naming the missing file and how to make the unit's keys."""
    d = Path(directory)
    files = {"ca": d / CA_CERT, "key": d / f"{role}.key", "cert": d / f"{role}.pem"}
    for f in files.values():
        if not f.is_file():
            raise FileNotFoundError(f"--keys {directory}: {f.name} is missing (make a unit's "
                                    "keys with: ctrlunit keys init DIR)")
    return {k: str(v) for k, v in files.items()}


def check_credentials(directory: str | Path, roles: list[str] | tuple[str, ...], *,
                      now: datetime.datetime | None = None) -> None:
    """Check, before anything starts, the keys directory ``directory`` for the ``roles``
    a run uses (``central``, ``plant``, ``peripheral-K``, ``viewer``; none: the directory
    and the authority alone), as ssh checks its keys:

    - the directory exists with ``ca.pem``, and no one but its owner may write it;
    - the authority's private key ``ca.key`` is not there (no role needs it, and whoever
      reads it can make a certificate for any role);
    - ``ca.pem`` parses (PEM), is a certificate authority's, is valid at ``now`` and no
      one but its owner may write it;
    - per role, ``ROLE.pem`` and ``ROLE.key`` exist; the key is its owner's alone (no
      group or other permission bits), the certificate writable by its owner only; the
      certificate parses, was issued by ``ca.pem``'s authority (issuer name and
      signature), its common name is the role's and it is valid at ``now``; the key
      parses, has no passphrase and is the certificate's (same public key).

    ``now`` is an aware datetime; None: the current time.

    Raises
    ------
    ValueError
        At the first failure, one line naming the file and the reason, with the fix where
        there is one (``--keys keys: plant.key is open to others (mode 0644; ...): chmod
        600 keys/plant.key``).
    """
    d, where = Path(directory), f"--keys {directory}"
    when = datetime.datetime.now(datetime.UTC) if now is None else now
    if not (d / CA_CERT).is_file():
        raise ValueError(f"{where}: no {CA_CERT} there (make a unit's keys with: ctrlunit "
                         "keys init DIR)")
    mode = d.stat().st_mode & 0o777
    if mode & 0o022:
        raise ValueError(f"{where}: {directory} can be written by others (mode {mode:04o}), "
                         f"who could replace the unit's keys: chmod 700 {directory}")
    if (d / CA_KEY).exists():
        from .keygen import authority_of

        raise ValueError(
            f"{where}: {CA_KEY} is there, the authority's private key: no role needs it, and "
            "whoever reads it can make a certificate for any role; move it off the unit's "
            f"hosts (e.g. mv {d / CA_KEY} {authority_of(d)}/)")
    _check_mode(d / CA_CERT, where, secret=False)
    ca = _read_cert(d / CA_CERT, where)
    _check_authority(ca, where, when)
    for role in roles:
        files = [d / f"{role}.pem", d / f"{role}.key"]
        for f in files:
            if not f.is_file():
                raise ValueError(f"{where}: {f.name} is missing (each host needs {CA_CERT} "
                                 "and its role's .pem and .key; make a unit's keys with: "
                                 "ctrlunit keys init DIR)")
            _check_mode(f, where, secret=f.suffix == ".key")
        cert = _read_cert(files[0], where)
        _check_issued(cert, ca, files[0].name, where)
        _check_name(cert, role, where)
        _check_time(cert, files[0].name, where, when)
        _check_key(files[1], files[0].name, cert, where)


def _check_mode(path: Path, where: str, *, secret: bool) -> None:
    """A private key must have no group or other permission bits, a certificate no group
    or other write bit."""
    mode = path.stat().st_mode & 0o777
    if secret and mode & 0o077:
        raise ValueError(f"{where}: {path.name} is open to others (mode {mode:04o}; a private "
                         f"key must be its owner's alone): chmod 600 {path}")
    if not secret and mode & 0o022:
        raise ValueError(f"{where}: {path.name} can be written by others (mode {mode:04o}), "
                         f"who could replace it: chmod 644 {path}")


def _read(path: Path, where: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{where}: {path.name} cannot be read ({exc.strerror})") from None


def _read_cert(path: Path, where: str) -> Any:
    from cryptography import x509

    try:
        return x509.load_pem_x509_certificate(_read(path, where))
    except ValueError:
        raise ValueError(f"{where}: {path.name} is not a readable PEM certificate (cut short "
                         "or damaged: copy it again from the unit's keys)") from None


def _check_authority(ca: Any, where: str, when: datetime.datetime) -> None:
    from cryptography import x509

    try:
        is_ca = ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    except x509.ExtensionNotFound:
        is_ca = False
    if not is_ca:
        raise ValueError(f"{where}: {CA_CERT} is not a certificate authority's (its basic "
                         "constraints do not say CA): give the unit's ca.pem")
    _check_time(ca, CA_CERT, where, when)


def _check_issued(cert: Any, ca: Any, name: str, where: str) -> None:
    from cryptography.exceptions import InvalidSignature, UnsupportedAlgorithm

    if cert.issuer != ca.subject:
        raise ValueError(f"{where}: {name} was issued by '{cert.issuer.rfc4514_string()}', "
                         f"not by the authority of {CA_CERT} "
                         f"('{ca.subject.rfc4514_string()}')")
    try:
        cert.verify_directly_issued_by(ca)
    except InvalidSignature:
        raise ValueError(f"{where}: {name} is not signed by the authority of {CA_CERT} (its "
                         "signature does not verify: another unit's certificate?)") from None
    except (ValueError, TypeError, UnsupportedAlgorithm) as exc:
        raise ValueError(f"{where}: {name}'s signature cannot be checked against {CA_CERT} "
                         f"({exc})") from None


def _check_name(cert: Any, role: str, where: str) -> None:
    from cryptography.x509.oid import NameOID

    cns = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    cn = cns[0].value if cns else None
    if cn != role:
        raise ValueError(f"{where}: {role}.pem is the certificate of {cn!r} (its common "
                         f"name), not of {role}" if cn is not None else
                         f"{where}: {role}.pem has no common name: it is not the certificate "
                         f"of {role}")


def _check_time(cert: Any, name: str, where: str, when: datetime.datetime) -> None:
    start, end = cert.not_valid_before_utc, cert.not_valid_after_utc
    if when > end:
        raise ValueError(f"{where}: {name} expired on {end:%Y-%m-%d %H:%M} UTC (make the "
                         "unit's keys again and replace them on every host)")
    if when < start:
        raise ValueError(f"{where}: {name} is valid only from {start:%Y-%m-%d %H:%M} UTC "
                         "(is this host's clock right?)")


def _check_key(path: Path, cert_name: str, cert: Any, where: str) -> None:
    from cryptography.exceptions import UnsupportedAlgorithm
    from cryptography.hazmat.primitives import serialization

    try:
        key = serialization.load_pem_private_key(_read(path, where), password=None)
    except TypeError:
        raise ValueError(f"{where}: {path.name} is encrypted with a passphrase, which a role "
                         "cannot give: use the key as ctrlunit keys init writes it") from None
    except (ValueError, UnsupportedAlgorithm):
        raise ValueError(f"{where}: {path.name} is not a readable PEM private key (cut short "
                         "or damaged: copy it again from the unit's keys)") from None
    spki = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    if key.public_key().public_bytes(*spki) != cert.public_key().public_bytes(*spki):
        raise ValueError(f"{where}: {path.name} does not match {cert_name} (the "
                         "certificate's public key differs)")


def _rule(rid: str, messages: list[str], keys: list[str], flows: list[str]) -> dict[str, Any]:
    return {"id": rid, "permission": "allow", "messages": messages, "key_exprs": keys,
            "flows": flows}


def access_control(peripherals: int = MAX_PERIPHERALS) -> dict[str, Any]:
    """The unit's access-control policy (Zenoh's ``access_control`` section), the same on
    every role's session; subjects are certificate common names (module notes)."""
    unit = "ctrlunit/*"
    roles = role_names(peripherals)
    units = [r for r in roles if r != VIEWER]
    rules = [
        _rule("subscribe", ["declare_subscriber"], ["ctrlunit/**"], ["ingress", "egress"]),
        _rule("send", ["put"], ["ctrlunit/**"], ["egress"]),
        _rule("hello", ["put"], [f"{unit}/central/hello"], ["ingress"]),
        _rule("sample", ["put"], [f"{unit}/central/sample"], ["ingress"]),
        _rule("orders", ["put"], [f"{unit}/plant/**", f"{unit}/peripheral/**"], ["ingress"]),
        *(_rule(f"reply-{k}", ["put"], [f"{unit}/central/reply/{k}"], ["ingress"])
          for k in range(1, peripherals + 1)),
    ]
    subjects = [{"id": r, "cert_common_names": [r]} for r in roles]
    policies = [
        {"id": "everyone", "rules": ["subscribe", "send"], "subjects": roles},
        {"id": "roles", "rules": ["hello"], "subjects": [r for r in units if r != "central"]},
        {"id": "plant", "rules": ["sample"], "subjects": ["plant"]},
        {"id": "central", "rules": ["orders"], "subjects": ["central"]},
        *({"id": f"peripheral-{k}", "rules": [f"reply-{k}"], "subjects": [f"peripheral-{k}"]}
          for k in range(1, peripherals + 1)),
    ]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def secure(conf: Any, directory: str | Path, role: str) -> None:
    """Make ``conf`` (a ``zenoh.Config``) authenticate as ``role`` with the unit's keys in
    ``directory`` and enforce :func:`access_control`. Names in certificates are roles, not
    host names: the peer is identified by its certificate's chain to the unit's authority
    and its common name, not by the address it was reached at."""
    c = credentials(directory, role)
    tls = {"root_ca_certificate": c["ca"], "enable_mtls": True,
           "listen_private_key": c["key"], "listen_certificate": c["cert"],
           "connect_private_key": c["key"], "connect_certificate": c["cert"],
           "verify_name_on_connect": False}
    conf.insert_json5("transport/link/tls", json.dumps(tls))
    conf.insert_json5("access_control", json.dumps(access_control()))


def tls_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT``; other endpoints (the local socket, tls) as
    they are."""
    return "tls/" + endpoint[4:] if endpoint.startswith("tcp/") else endpoint


def reaches_beyond_host(endpoint: str) -> bool:
    """Whether an endpoint can be reached from another host: anything but a unix socket
    or a loopback address (127.0.0.0/8, ::1, localhost)."""
    proto, _, addr = endpoint.partition("/")
    if proto.startswith("unixsock"):
        return False
    host = addr.rsplit(":", 1)[0].strip("[]") if ":" in addr else addr
    host = host.split("?")[0].split("#")[0]
    if host == "localhost":
        return False
    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:
        return True  # a host name other than localhost


def link_security(listen: list[str] | None, connect: list[str] | None, keys: str | None,
                  insecure: bool) -> str:
    """How a role's links are protected, for the report: ``tls`` (with ``keys``),
    ``local`` (unix sockets only), ``loopback`` (a loopback address without keys: any
    process on this host may connect) or ``insecure`` (beyond the host, ``--insecure``).

    Raises
    ------
    ValueError
        A link beyond the host without keys or ``--insecure``, naming the endpoint and
        the fix."""
    eps = [*(listen or []), *(connect or [])]
    if keys:
        return "tls"
    beyond = [e for e in eps if reaches_beyond_host(e)]
    if beyond and not insecure:
        raise ValueError(
            f"{beyond[0]} can be reached from other hosts, and without keys anyone who can "
            "reach it may read the unit's traffic and move the robot: make keys with "
            "'ctrlunit keys init DIR' and give --keys DIR to every role, or --insecure for "
            "a lab bench")
    if beyond:
        return "insecure"
    return "loopback" if any(not e.startswith("unixsock") for e in eps) else "local"
