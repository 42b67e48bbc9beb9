"""Machinery shared by every learner: the config base and its option groups ('config'), the run
skeleton ('run'), tasks, rollouts, buffers, networks, losses, demonstrations, checkpoints,
logging and evaluation (with 'evaluate.load_policy' and 'Policy.predict'). The methods
themselves live in 'hybridmarl.algos'."""
