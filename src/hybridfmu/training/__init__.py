"""Training of the neural FMU: maneuver arrays, windows and batching, losses, the solver, trials with
checkpoints, Hyperband (bracket arithmetic, selection), search-space sampling, and inference."""
