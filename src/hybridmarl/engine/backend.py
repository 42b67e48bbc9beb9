"""Which engine backend a command uses: the JAX engine (the reference, and the one for GPUs and
code under ``jit``) or the native one (Numba, the fast one on a CPU). See
docs/engine-backends.md."""

from __future__ import annotations

ENGINES = ("auto", "native", "jax")


def resolve_engine(value: str) -> str:
    """``native`` or ``jax`` for an ``--engine`` value: ``auto`` is native when JAX's default
    backend is the CPU and jax otherwise (a GPU)."""
    if value not in ENGINES:
        raise ValueError(f"unknown engine {value!r} (known: {', '.join(ENGINES)})")
    if value != "auto":
        return value
    import jax

    return "native" if jax.default_backend() == "cpu" else "jax"


__all__ = ["ENGINES", "resolve_engine"]
