"""``ctrlunit keys``: a unit's credentials (runtime/transport/security.py)."""

from __future__ import annotations

import click

from ..config import EXIT_CONFIG
from .base import FilePath, _fail, cli


@cli.group()
def keys() -> None:
    """A unit's credentials: one authority, a key and certificate per role."""


@keys.command("init")
@click.argument("directory", type=FilePath(file_okay=False))
@click.option("--authority", type=FilePath(file_okay=False), default=None,
              help="Where the authority's private key ca.key goes, apart from the roles' "
              "keys (made 0700)  [default: DIRECTORY-authority beside DIRECTORY]")
@click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True,
              help="Peripheral certificates to make (peripheral-1 to -N).")
def keys_init(directory: str, authority: str | None, peripherals: int) -> None:
    """Write a certificate authority and a key and certificate per role (central, plant,
    peripheral-1..N, viewer) into DIRECTORY (0700; keys 0600, certificates 0644), and the
    authority's private key apart (--authority); give --keys DIRECTORY to every role
    (each host needs ca.pem and its own role's two files only). Nothing is overwritten."""
    from ..transport.security import make_keys, role_names

    try:
        files = make_keys(directory, authority=authority, peripherals=peripherals)
    except (FileExistsError, OSError, ValueError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    held = files[-2]  # the authority's key: make_keys lists the authority's two last
    click.echo(f"wrote {len(files) - 2} files into {directory}: ca.pem (every host) and "
               f"ROLE.pem, ROLE.key for {', '.join(role_names(peripherals))}; the "
               f"authority's key into {held} (keep it off the unit's hosts: it makes "
               "certificates for any role; no role needs it)")
