"""``python -m ctrlunit.runtime.cli``: the same as the ``ctrlunit`` command."""

from . import main

main()
