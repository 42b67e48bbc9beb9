"""``make_player``: build any player from a spec string (grammar in ``hybridmarl.search.base``)."""

from __future__ import annotations

from typing import Any

from hybridmarl.engine.scripts import canonical_name
from hybridmarl.search.base import (
    _NAME_ALIASES,
    ALGORITHMS,
    Player,
    ScriptPlayer,
    parse_spec,
    resolve_options,
)


def make_player(spec: str, **options: Any) -> Player:
    """A player from ``spec`` (``"uct"``, ``"abcd:time_ms=0,nodes=500"``, ``"pgs"``, a script
    name, ...); keyword ``options`` override the spec's. Raises ``ValueError`` with a one-line
    message for an unknown name, an unknown option or a bad value."""
    name, raw = parse_spec(spec)
    key = name.lower().replace("_", "-")
    alg = _NAME_ALIASES.get(key)
    if alg is None:
        try:
            script = canonical_name(name)
        except KeyError:
            algs = ", ".join(sorted(_NAME_ALIASES))
            raise ValueError(
                f"unknown player {name!r}: use a search ({algs}) or a script name"
            ) from None
        if raw or options:
            raise ValueError(f"player spec {spec!r}: scripts take no options")
        return ScriptPlayer(script)
    merged: dict[str, Any] = dict(raw)
    merged.update({k.lower().replace("-", "_"): v for k, v in options.items()})
    values = resolve_options(alg, merged, f"player spec {spec!r}")
    assert alg in ALGORITHMS
    label = spec.strip() if not options else f"{spec.strip()} {options}"
    if alg == "uct":
        from hybridmarl.search.uct import UCTPlayer

        return UCTPlayer(values, name=label)
    if alg == "abcd":
        from hybridmarl.search.abcd import ABCDPlayer

        return ABCDPlayer(values, name=label)
    from hybridmarl.search.pgs import PGSPlayer

    return PGSPlayer(values, name=label)
