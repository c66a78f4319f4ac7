"""Off-robot and on-robot services: each a pure core plus a thin Zenoh node."""
