"""Starting a unit on this host: the admission trial, the lifecycle of a start, the launcher."""
