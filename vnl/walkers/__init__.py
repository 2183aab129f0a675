"""Walkers (animal bodies) as PyMJCF models built from their upstream sources."""
