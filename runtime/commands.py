"""Run-time commands of the ``ctrlunit`` CLI (registered on import)."""
