"""The roles other than the central (peripheral, plant) and what supervises and stops a
role's process."""
