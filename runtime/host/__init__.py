"""What the unit asks of the host it runs on: the scheduling policy and its guard, the
CPUs' idle states."""
