"""A unit's keys checked before anything starts, as ssh checks its own
(:func:`check_credentials`): the keys directory and the authority's certificate, then
each role's key and certificate. Each failure is one line naming the file and the reason
(docs/faults-and-errors.md, Security)."""

from __future__ import annotations

import datetime
import os
import stat
from pathlib import Path
from typing import Any

CA_CERT = "ca.pem"
CA_KEY = "ca.key"


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
    check_folders(d / CA_CERT, where)
    if (d / CA_KEY).exists():
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
            if f.exists() and not f.is_file():
                raise ValueError(f"{where}: {f.name} is not a regular file (a directory, a "
                                 "pipe or a device): give the role's file there")
            if not f.is_file():
                raise ValueError(f"{where}: {f.name} is missing (each host needs {CA_CERT} "
                                 "and its role's .pem and .key; make a unit's keys with: "
                                 "ctrlunit keys init DIR)")
            check_folders(f, where)
            _check_mode(f, where, secret=f.suffix == ".key")
        cert = _read_cert(files[0], where)
        _check_issued(cert, ca, files[0].name, where)
        _check_name(cert, role, where)
        _check_time(cert, files[0].name, where, when)
        _check_key(files[1], files[0].name, cert, where)


def authority_of(directory: str | Path) -> Path:
    """The authority's directory by default: ``DIR-authority`` beside ``directory``
    (``keys/`` -> ``keys-authority``; ``.`` is named by its absolute path)."""
    d = Path(directory)
    if d.name in ("", ".", ".."):
        d = d.resolve()
    return d.parent / f"{d.name}-authority"


def check_folders(path: Path, where: str) -> None:
    """Every folder above the file ``path`` is (through any symbolic link: its target's
    folders) owned by this user or root and writable by no one else, as ssh checks the
    folders above its keys: whoever may write one could put another file, or another
    folder, in its place. A folder with the sticky bit (``/tmp``) is allowed: there no
    one but an entry's owner may replace it."""
    real, uid = path.resolve(), os.geteuid()
    for folder in real.parents:
        st = folder.stat()
        if st.st_uid not in (uid, 0):
            raise ValueError(f"{where}: {path.name} lies in {folder}, which belongs to another "
                             f"user (uid {st.st_uid}), who could replace it")
        mode = st.st_mode & 0o7777
        if mode & 0o022 and not mode & stat.S_ISVTX:
            raise ValueError(f"{where}: {path.name} lies in {folder}, which others can write "
                             f"(mode {mode & 0o777:04o}), who could replace it: chmod go-w "
                             f"{folder}")


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
