"""A unit's credentials written to disk (``ctrlunit keys init DIR``), as ssh keeps keys:
the keys directory 0700, each private key 0600, each certificate 0644, whatever the
umask, and nothing ever overwritten.

The authority's private key (``ca.key``) is written apart, into its own directory (0700,
by default the keys directory's sibling ``<DIR>-authority``), with a copy of its
certificate: no role needs it at run time, and a host that holds it can make a
certificate for any role, so it is kept off the unit's hosts. The keys directory holds
what the roles read: ``ca.pem`` and a key and certificate per role."""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path
from typing import Any

from .keycheck import authority_of, check_folders

KEY_MODE, CERT_MODE, DIR_MODE = 0o600, 0o644, 0o700


def _refuse_open_dir(path: Path) -> None:
    """Refuse an existing ``path`` that others may write (they could replace the keys):
    its mode is the user's to set, not changed here."""
    if path.exists():
        mode = path.stat().st_mode & 0o7777
        if not path.is_dir():
            raise ValueError(f"{path} is not a directory")
        if mode & 0o022:
            raise ValueError(f"{path} can be written by others (mode {mode:04o}), who could "
                             f"replace the keys: chmod 700 {path}, or choose a new directory")
    # the folders above it as the run checks them (owner, write bits), before any is made
    here = next(d for d in (path, *path.absolute().parents) if d.exists())
    check_folders(here / "ca.pem", f"keys init {path}")


def _private_dir(path: Path) -> None:
    """Make ``path`` (and its parents) at 0700 whatever the umask; an existing one is left
    as it is (:func:`_refuse_open_dir` checked it)."""
    if not path.exists():
        path.mkdir(parents=True)
        os.chmod(path, DIR_MODE)


def _write(path: Path, data: bytes, mode: int) -> None:
    """Create ``path`` (never an existing one: :class:`FileExistsError`) with ``mode``
    set explicitly, so that the umask neither widens nor narrows it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as fh:
        os.fchmod(fh.fileno(), mode)
        fh.write(data)


def write_keys(directory: str | Path, names: list[str], *, authority: str | Path | None,
               days: int, ca_cert: str, ca_key: str) -> list[Path]:
    """Write an authority and a key and certificate per role of ``names`` (module notes).

    Parameters
    ----------
    directory : the keys directory (made at 0700 if missing; an existing one keeps its
        mode, and is refused if others may write it).
    names : the roles, each certificate's common name.
    authority : where ``ca_key`` and a copy of ``ca_cert`` go (made if missing; 0700);
        None: :func:`authority_of` ``directory``. It must not be ``directory`` itself.
    days : how long the certificates are valid, from 5 minutes ago.
    ca_cert, ca_key : the file names of the authority's certificate and key.

    Returns the files written, the authority's last.

    Raises
    ------
    FileExistsError
        Naming the first file that exists, before anything is written.
    ValueError
        If the authority's directory is the keys directory, or either exists and others
        may write it.
    """
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    out = Path(directory)
    auth = authority_of(out) if authority is None else Path(authority)
    if auth.resolve() == out.resolve():
        raise ValueError(f"--authority {auth}: the authority's key must be kept apart from "
                         f"the keys the roles read, not in {out} itself")
    files = [out / ca_cert] + [out / f"{r}.{x}" for r in names for x in ("pem", "key")]
    kept = [auth / ca_key, auth / ca_cert]
    for f in files + kept:
        if os.path.lexists(f):  # a link to nothing too: it would fail half-way
            raise FileExistsError(f"{f} exists: keys are never overwritten (choose another "
                                  "directory)")
    for d in (out, auth):
        _refuse_open_dir(d)
    _private_dir(out)
    _private_dir(auth)
    now = datetime.datetime.now(datetime.UTC)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)
    key = ec.generate_private_key(ec.SECP256R1())
    ca = _authority(key, start, end)
    pem = ca.public_bytes(serialization.Encoding.PEM)
    _write(out / ca_cert, pem, CERT_MODE)
    for role in names:
        role_key = ec.generate_private_key(ec.SECP256R1())
        cert = _role_cert(role, role_key, ca, key, start, end)
        _write(out / f"{role}.pem", cert.public_bytes(serialization.Encoding.PEM), CERT_MODE)
        _write(out / f"{role}.key", _key_bytes(role_key), KEY_MODE)
    _write(auth / ca_key, _key_bytes(key), KEY_MODE)
    _write(auth / ca_cert, pem, CERT_MODE)
    return files + kept


def _key_bytes(key: Any) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _name(cn: str) -> Any:
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ctrlunit"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _usage(**allowed: bool) -> Any:
    from cryptography import x509

    names = ("digital_signature", "content_commitment", "key_encipherment",
             "data_encipherment", "key_agreement", "key_cert_sign", "crl_sign",
             "encipher_only", "decipher_only")
    return x509.KeyUsage(**{k: allowed.get(k, False) for k in names})


def _authority(key: Any, start: datetime.datetime, end: datetime.datetime) -> Any:
    """The unit's ECDSA P-256 authority, self-signed, for certificates only."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    name = _name("ctrlunit unit authority")
    return (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(_usage(digital_signature=True, key_cert_sign=True, crl_sign=True),
                           critical=True)
            .sign(key, hashes.SHA256()))


def _role_cert(role: str, key: Any, ca: Any, ca_key: Any, start: datetime.datetime,
               end: datetime.datetime) -> Any:
    """``role``'s certificate, for both TLS server and client use, its common name the
    role's name, signed by the authority ``ca`` (``ca_key``)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID

    return (x509.CertificateBuilder().subject_name(_name(role)).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_usage(digital_signature=True), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName([
                x509.DNSName("localhost"),
                x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .sign(ca_key, hashes.SHA256()))
