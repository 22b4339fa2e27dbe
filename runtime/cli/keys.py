"""``ctrlunit keys``: a unit's credentials (runtime/transport/security.py)."""

from __future__ import annotations

import click

from ..config import EXIT_CONFIG
from .base import _fail, cli


@cli.group()
def keys() -> None:
    """A unit's credentials: one authority, a key and certificate per role."""


@keys.command("init")
@click.argument("directory", type=click.Path(file_okay=False))
@click.option("--peripherals", type=click.IntRange(0, 3), default=3, show_default=True,
              help="Peripheral certificates to make (peripheral-1 to -N).")
def keys_init(directory: str, peripherals: int) -> None:
    """Write a certificate authority and a key and certificate per role (central, plant,
    peripheral-1..N, viewer) into DIRECTORY; give --keys DIRECTORY to every role (each
    host needs ca.pem and its own role's two files only). Nothing is overwritten."""
    from ..transport.security import make_keys, role_names

    try:
        files = make_keys(directory, peripherals=peripherals)
    except (FileExistsError, OSError) as exc:
        _fail(str(exc), EXIT_CONFIG)
        return
    click.echo(f"wrote {len(files)} files into {directory}: ca.pem (every host), ca.key "
               "(keep it off the unit's hosts) and ROLE.pem, ROLE.key for "
               + ", ".join(role_names(peripherals)))
