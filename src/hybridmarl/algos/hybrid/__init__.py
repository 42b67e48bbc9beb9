"""The hybrid learning method (Peng, Xing & Cao, IJCAI 2020): options and presets ('config'),
the compiled learner ('learner'), best-response dynamics ('brd', Alg. 1) and the run ('train')."""

from hybridmarl.algos.hybrid.config import PRESETS, HybridConfig
from hybridmarl.algos.hybrid.learner import Learner, build_learner
from hybridmarl.algos.hybrid.train import ALGO, train

#: The config class of '--algo hybrid'.
CONFIG = HybridConfig

__all__ = ["ALGO", "CONFIG", "PRESETS", "HybridConfig", "Learner", "build_learner", "train"]
