"""PPO, the algorithm: Brax's PPO composed from its own building blocks one epoch at a time
(`loop`), its networks (`networks`, with vision `conv`; recurrent cores `recurrent`,
`recurrent_ppo`), its schedules and its settings (`config`). Run management (run directories,
checkpoints, signals, sessions, curricula) is `vnl.train`'s; this package reads a run's config
through `config.RunSettings` and knows nothing of files.
"""
