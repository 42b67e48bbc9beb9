"""Native CPU backend of the SparCraft combat engine: Numba kernels over NumPy arrays.

The JAX engine (``hybridmarl.engine``) is the reference; this backend plays the same games with
the same results (winner, frames, turns, every unit's HP; the whole state after every turn), one
game per thread-chunk, a batch in parallel. See ``docs/engine-backends.md``.

Threading layer: Numba's OpenMP layer (GNU libgomp) is preferred, because it is thread-safe
(the default ``workqueue`` layer aborts the process when two Python threads launch parallel
kernels at once) and XLA, which runs its own thread pool and no OpenMP, does not share it. TBB,
also thread-safe, comes next; ``workqueue`` is the last resort. A ``NUMBA_THREADING_LAYER``
set by the user wins. This must happen before the first parallel kernel runs, hence here.
"""

from __future__ import annotations

import os

from numba import config as _numba_config

# libgomp's worker threads otherwise spin for a while after each parallel region, taking the
# cores from the XLA calls that follow it in the same process (training alternates the two).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
if "NUMBA_THREADING_LAYER" not in os.environ:
    _numba_config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]  # type: ignore[attr-defined]

from hybridmarl.engine.native.play import (  # noqa: E402
    NativeResults,
    advance,
    apply_actions,
    compile_kernels,
    play,
    record_trace,
    run_battles,
    step,
    threading_layer,
)
from hybridmarl.engine.native.state import (  # noqa: E402
    NativeStates,
    build_native_states,
    from_arrays,
    from_jax,
    to_jax,
)

__all__ = [
    "NativeResults",
    "NativeStates",
    "advance",
    "apply_actions",
    "build_native_states",
    "compile_kernels",
    "from_arrays",
    "from_jax",
    "play",
    "record_trace",
    "run_battles",
    "step",
    "threading_layer",
    "to_jax",
]
