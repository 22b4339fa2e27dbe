"""The ``ctrlunit`` command line (click): one module per family of commands.

``base`` holds the group and the shared helpers; ``kinematics`` (ik, fk, trajectory,
workspace), ``run`` (start, config), ``roles`` (central, plant, peripheral),
``recordings`` (replay, report), ``tools`` (bench, latency), ``balance`` and ``keys``
(keys init) register their commands on it when imported here.
"""

from __future__ import annotations

from . import balance, keys, kinematics, recordings, roles, run, tools
from .base import cli

__all__ = ["balance", "cli", "keys", "kinematics", "main", "recordings", "roles", "run",
           "tools"]


def main() -> None:
    """Entry point of the ``ctrlunit`` console script (and of ``python -m``)."""
    cli(prog_name="ctrlunit")
