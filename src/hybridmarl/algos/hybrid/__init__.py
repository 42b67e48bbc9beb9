"""The hybrid learning method (Peng, Xing & Cao, IJCAI 2020): see :mod:`hybridmarl.algos.hybrid.train`."""

from hybridmarl.algos.hybrid.train import ALGO, PRESETS, HybridConfig, Learner, build_learner, train

__all__ = ["ALGO", "PRESETS", "HybridConfig", "Learner", "build_learner", "train"]
