"""How the roles talk: Zenoh sessions and their security, the node (inbox and publishers)
and the message codec."""
