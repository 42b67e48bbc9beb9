"""The numbers a user gives, checked once before any work starts.

Every option of a command (``--num-envs``, ``--gamma``, ``--n``) and every number of a saved run
config is checked against one rule here: a size, count or interval is at least 1 (or at least 0
where 0 means "off"), a probability lies in [0, 1], a discount in [0, 1), a learning rate is a
finite positive number, and no float is NaN or infinite. A value that breaks its rule raises one
:class:`~hybridmarl.errors.UserError` line naming the option and the value.

A learner's config is checked field by field through :data:`FIELD_RULES` (by the flat field
name, shared by every learner); a field not listed there gets the rule of its type (an integer
at least 0, a finite float), so a new field is never left unchecked.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from hybridmarl.errors import UserError

#: A rule: the value -> None if it is valid, else what it must be ("at least 1").
Rule = Callable[[Any], "str | None"]


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def int_at_least(low: int) -> Rule:
    def rule(v: Any) -> str | None:
        if not _is_int(v):
            return f"an integer at least {low}"
        return None if v >= low else f"at least {low}"

    return rule


def number_in(low: float, high: float, *, high_open: bool = False) -> Rule:
    def rule(v: Any) -> str | None:
        ok = (
            _is_number(v)
            and math.isfinite(v)
            and low <= v
            and (v < high if high_open else v <= high)
        )
        return None if ok else f"a number in [{low:g}, {high:g}{')' if high_open else ']'}"

    return rule


def finite(*, low: float | None = None, strict: bool = False) -> Rule:
    def rule(v: Any) -> str | None:
        if not (_is_number(v) and math.isfinite(v)):
            return (
                "a finite number"
                if low is None
                else f"a finite number {'>' if strict else '>='} {low:g}"
            )
        if low is not None and (v <= low if strict else v < low):
            return f"a number {'>' if strict else '>='} {low:g}"
        return None

    return rule


def optional(rule: Rule) -> Rule:
    """``rule``, or None (the option's "default"/"off")."""

    def check(v: Any) -> str | None:
        return None if v is None else rule(v)

    return check


def layer_sizes(v: Any) -> str | None:
    ok = isinstance(v, tuple | list) and len(v) > 0 and all(_is_int(x) and x >= 1 for x in v)
    return None if ok else "a non-empty list of layer sizes, each at least 1"


def int_in(low: int, high: int) -> Rule:
    def rule(v: Any) -> str | None:
        return None if _is_int(v) and low <= v <= high else f"an integer in [{low}, {high}]"

    return rule


COUNT = int_at_least(1)
#: A seed: what NumPy's and JAX's generators both take.
SEED = int_in(0, 2**32 - 1)
COUNT_OR_ZERO = int_at_least(0)
PROBABILITY = number_in(0.0, 1.0)
DISCOUNT = number_in(0.0, 1.0, high_open=True)
POSITIVE = finite(low=0.0, strict=True)
NON_NEGATIVE = finite(low=0.0)

#: Rules of the learners' config fields, by flat field name (every learner shares the names).
FIELD_RULES: dict[str, Rule] = {
    # sizes, counts, intervals: at least 1
    **{
        name: COUNT
        for name in (
            "actor_steps",
            "batch_size",
            "bc_batch_size",
            "bc_steps",
            "brd_iterations",
            "brd_work_batch",
            "buffer_size",
            "checkpoint_every",
            "chunk_steps",
            "critic_batch_size",
            "critic_pretrain_steps",
            "critic_update_steps",
            "demo_observations",
            "e_update",
            "eval_episodes",
            "keep_checkpoints",
            "max_turns",
            "n_step",
            "num_envs",
            "target_update_every",
            "total_episodes",
            "train_every",
            "updates_per_call",
        )
    },
    # 0 means "off" or "none"
    **{
        name: COUNT_OR_ZERO
        for name in (
            "eval_every",
            "lookahead_steps",
            "eps_decay_episodes",
            "agreement_decay_episodes",
            "pretrain_samples",
            "pretrain_updates",
        )
    },
    "seed": SEED,
    "actor_average_from": optional(COUNT_OR_ZERO),
    "actor_lr_decay_from": optional(COUNT_OR_ZERO),
    "gamma": DISCOUNT,
    **{name: PROBABILITY for name in ("eps_start", "eps_end", "per_alpha", "per_beta0")},
    "p_arrive": optional(PROBABILITY),
    **{name: POSITIVE for name in ("lr", "actor_lr", "critic_lr")},
    **{
        name: NON_NEGATIVE
        for name in (
            "lambda_l2",
            "lambda_margin",
            "lambda_nstep",
            "margin",
            "agreement_bonus",
            "per_eps_agent",
            "per_eps_demo",
            "time_limit_min",
        )
    },
    "lambda_margin_online": optional(NON_NEGATIVE),
    "actor_hidden": layer_sizes,
    "critic_hidden": layer_sizes,
}


def rule_for(name: str, value: Any) -> Rule | None:
    """The rule of field ``name``: :data:`FIELD_RULES`, else by the value's type."""
    if name in FIELD_RULES:
        return FIELD_RULES[name]
    if _is_int(value):
        return COUNT_OR_ZERO
    if isinstance(value, float):
        return finite()
    return None


def option_name(field: str) -> str:
    """The command-line spelling of a field (``num_envs`` -> ``--num-envs``)."""
    return "--" + field.replace("_", "-")


def check_values(
    values: Mapping[str, Any],
    rules: Mapping[str, Rule] | None = None,
    *,
    label: Callable[[str], str] = option_name,
    error: type[UserError] = UserError,
) -> None:
    """Check every ``name: value`` against its rule (``rules``, else :func:`rule_for`); the first
    one that breaks its rule raises ``error``: "<label(name)> must be <rule>, got <value>"."""
    for name, value in values.items():
        rule = (rules or {}).get(name) or rule_for(name, value)
        problem = rule(value) if rule is not None else None
        if problem is not None:
            raise error(f"{label(name)} must be {problem}, got {value!r}")


def check_config(
    cfg: Any, *, label: Callable[[str], str] = option_name, error: type[UserError] = UserError
) -> None:
    """Check every field of a learner's config (``TrainConfig``: flat field names) or of a
    command's own config dataclass."""
    names: Iterable[str] = (
        cfg.field_names()
        if hasattr(cfg, "field_names")
        else [f.name for f in dataclasses.fields(cfg)]
    )
    check_values({n: getattr(cfg, n) for n in names}, label=label, error=error)


__all__ = [
    "COUNT",
    "COUNT_OR_ZERO",
    "DISCOUNT",
    "FIELD_RULES",
    "NON_NEGATIVE",
    "POSITIVE",
    "PROBABILITY",
    "SEED",
    "check_config",
    "check_values",
    "finite",
    "int_at_least",
    "int_in",
    "number_in",
    "option_name",
    "optional",
    "rule_for",
]
