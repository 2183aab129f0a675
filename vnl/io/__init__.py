"""Run-directory I/O: checkpoints, metrics, plots, videos."""
