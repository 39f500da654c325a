"""Held-out evaluation: the protocol (days, keys, car draws), the references and paired
statistics. References stored on disk are read only from a path that is passed in."""
