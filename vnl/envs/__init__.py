"""Environments: the `Env` base class, `State`, training wrappers and the registry."""
