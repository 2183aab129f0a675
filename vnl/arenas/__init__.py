"""Arenas (worlds a walker is placed in), built with PyMJCF as in dm_control."""
