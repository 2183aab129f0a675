"""Tasks: one file per task, each with a frozen config dataclass and an `Env` subclass."""
