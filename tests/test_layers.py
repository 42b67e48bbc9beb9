"""The package's layers (docs/architecture.md#layers): every module imports only from its own
layer or the layers below it, function-level imports included."""

from __future__ import annotations

import ast
from pathlib import Path

import hybridmarl

PACKAGE = Path(hybridmarl.__file__).parent

#: Top-level module or subpackage of hybridmarl -> its layer (docs/architecture.md#layers).
LAYERS = {
    "errors": 0,
    "io": 0,
    "validate": 0,
    "options": 0,
    "engine": 1,
    "settings": 1,
    "envs": 2,
    "search": 2,
    "training": 3,
    "viewer": 3,
    "algos": 4,
    "reproduce": 5,
    "cli": 6,
}

#: (importing module, imported package): the documented exceptions.
ALLOWED_UPWARD = {
    # A run directory names its learner; reading its config.json looks the learner's config
    # class up in the registry (docs/architecture.md#layers).
    ("hybridmarl.training.rundir", "algos"),
}


def _imports(path: Path) -> set[str]:
    """The hybridmarl top-level names that a source file imports, anywhere in it."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        modules: list[str] = []
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules = [node.module]
            if node.module == "hybridmarl":
                modules = [f"hybridmarl.{alias.name}" for alias in node.names]
        names |= {m.split(".")[1] for m in modules if m.startswith("hybridmarl.")}
    return names


def test_every_module_has_a_layer() -> None:
    modules = {p.stem for p in PACKAGE.glob("*.py") if p.name != "__init__.py"}
    packages = {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    tops = modules | packages
    assert tops - set(LAYERS) == set(), "give the new module a layer (and docs/architecture.md)"


def test_no_module_imports_a_higher_layer() -> None:
    violations = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts == ("__init__.py",):
            continue  # the package's front door re-exports the public API of every layer
        module = "hybridmarl." + ".".join(rel.with_suffix("").parts).removesuffix(".__init__")
        own = LAYERS[rel.parts[0].removesuffix(".py")]
        for name in _imports(path):
            if name in LAYERS and LAYERS[name] > own and (module, name) not in ALLOWED_UPWARD:
                violations.append(f"{module} imports hybridmarl.{name}")
    assert violations == []


def test_the_library_never_imports_the_command_line() -> None:
    for path in PACKAGE.rglob("*.py"):
        if path.relative_to(PACKAGE).parts[0] != "cli":
            assert "cli" not in _imports(path), path
