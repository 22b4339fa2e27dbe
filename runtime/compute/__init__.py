"""What an interval computes and how it is measured: the blocks and their engine, the
controller's sources and estimate, the control rate, the setup of a run's plan."""
