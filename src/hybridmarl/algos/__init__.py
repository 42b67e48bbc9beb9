"""Learners: the hybrid method of Peng, Xing & Cao (IJCAI 2020) and the machinery it shares.

Modules:

- ``hybrid``: the method, top to bottom (Phase 1 demonstrator, Phase 2 critic pre-training
  Eq. 3, Phase 3 joint update Alg. 2 with Alg. 1 / Eq. 7 / Eq. 8, Phase 4 evaluation), its
  config (``HybridConfig``) and presets (``paper``, ``quick``, ``quick-paper``, ``traffic-junction``,
  ``wo-d``, ``quick-wo-d``, ``quick-rollout``, ``toy``; ``quick-lookahead`` is ``quick``'s old name);
- ``bc``: behavioural cloning (the paper's BC baseline and its θ^D);
- ``brd``: Alg. 1, best-response dynamics, batched over games under ``jit``;
- ``losses``: returns (Eq. 1), critic loss (Eq. 3), advantage (Eq. 7), actor loss (Eq. 8), BC loss;
- ``networks``: the actor (FC 512-256-256-|A|) and critic (FC 256-128-128-1), batch norm;
- ``demos``: demonstration datasets (record, save/load, validate), behavioural cloning;
- ``tasks``: the environment adapter every learner uses (demonstrators, one-step look-ahead);
- ``rollout``: parallel games with resets, episode assembly, the buffer B;
- ``common``: the config base, run directories, NaN checks, the ``--algo`` registry;
- ``checkpoint``: atomic safetensors + JSON checkpoints, keep-last-k, exact resume;
- ``logger``: CSV, TensorBoard, the progress display; ``plots``: the Fig. 3-style curve;
- ``evaluate``: the Section 5.1 protocol (W, R, 95% intervals), loading trained policies;
- ``cli``: ``hybridmarl train`` / ``eval`` / ``demos``.

Quick start::

    hybridmarl train --algo hybrid --preset quick --scenario m5v5 \\
        --demonstrator attack-closest --enemy attack-weakest --seed 0 --run-dir runs/m5v5-c
    hybridmarl eval --run-dir runs/m5v5-c --enemy attack-weakest --n 100 --seed 0 --json

Adding a learner (DQfD, OGTL, ...): a module with a frozen config deriving from
``common.TrainConfig``, a ``PRESETS`` dict and ``train(cfg) -> int``, registered in
``common.ALGOS``; it then gets ``hybridmarl train --algo NAME`` and ``hybridmarl eval`` for free
if it saves its actor under ``actor.*`` in its checkpoints (see ``bc``).
"""
