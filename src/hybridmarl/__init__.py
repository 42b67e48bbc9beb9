"""hybridmarl: hybrid learning for multi-agent cooperation from sub-optimal demonstrations.

Layout:
- ``hybridmarl.engine``: SparCraft's combat rules, frame-exact, as pure JAX functions.
- ``hybridmarl.envs``: the paper's environments (combat Dec-POMDP, Traffic Junction).
- ``hybridmarl.cli``: the ``hybridmarl`` command.
"""

__version__ = "0.1.0"
