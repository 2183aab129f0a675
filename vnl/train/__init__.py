"""Training: typed configs and presets, and the Brax PPO adapter."""
