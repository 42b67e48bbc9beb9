"""Machinery shared by every learner: tasks, rollouts, buffers, networks, losses, demonstrations,
checkpoints, logging and evaluation. The methods themselves live in :mod:`hybridmarl.algos`."""
