"""The package's layout as docs/architecture.md states it, checked on the source: imports
point one way along the chain of packages, and the pure layers never call ``jit`` (their
callers jit at their boundary)."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "jaxloco"

CHAIN = (
    "validation",
    "runtime",
    "config",
    "planner",
    "learning",
    "dynamics",
    "robots",
    "control",
    "locomotion",
    "sim",
    "viz",
    "sweep",
    "tuning",
    "app",
    "cli",
)
"""Every module and subpackage of ``jaxloco``, each importing only from those before it."""

PURE = ("planner", "dynamics", "control", "locomotion")
"""Packages of pure functions over pytrees: no ``jit`` inside."""


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).parts
        if parts == ("__init__.py",):
            continue
        yield path, parts[0].removesuffix(".py"), ast.parse(path.read_text())


def _imported(node) -> list[str]:
    if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
        names = [node.module]
    elif isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        return []
    return [n.split(".")[1] for n in names if n.startswith("jaxloco.")]


def test_every_part_of_the_package_has_its_place_in_the_chain():
    assert {part for _, part, _ in _modules()} == set(CHAIN)


def test_imports_point_one_way_along_the_chain():
    backwards = [
        f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {part} imports {target}"
        for path, part, tree in _modules()
        for node in ast.walk(tree)
        for target in _imported(node)
        if CHAIN.index(target) > CHAIN.index(part)
    ]
    assert not backwards, "\n".join(backwards)


@pytest.mark.parametrize("part", PURE)
def test_the_pure_layers_never_call_jit(part):
    calls = [
        f"{path.relative_to(PACKAGE.parent)}:{node.lineno}"
        for path, p, tree in _modules()
        if p == part
        for node in ast.walk(tree)
        if (isinstance(node, ast.Name) and node.id == "jit")
        or (isinstance(node, ast.Attribute) and node.attr == "jit")
    ]
    assert not calls, "jit belongs to the drivers (sim, sweep, tuning, training):\n" + "\n".join(
        calls
    )


def test_only_the_runtime_changes_jax_config_for_the_process():
    """Process-wide JAX settings change in ``jaxloco.runtime`` only; elsewhere a setting
    (e.g. float64 for a sweep's job) is a context (``jax.enable_x64(...)``) around the work."""
    sources = [*PACKAGE.rglob("*.py"), *(PACKAGE.parent / "experiments").glob("*.py")]
    calls = [
        f"{path.relative_to(PACKAGE.parent)}:{node.lineno}"
        for path in sorted(sources)
        if path != PACKAGE / "runtime.py"
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.Attribute)
        and node.attr == "update"
        and isinstance(node.value, ast.Attribute)
        and node.value.attr == "config"
    ]
    assert not calls, "\n".join(calls)


def _is_record(node: ast.ClassDef) -> bool:
    """A dataclass (``dataclasses``' or flax's) or a ``NamedTuple``."""
    decorators = [ast.unparse(d) for d in node.decorator_list]
    bases = [ast.unparse(b) for b in node.bases]
    return any("dataclass" in d for d in decorators) or "NamedTuple" in bases


def test_every_dataclass_field_has_a_docstring():
    """Each field of every dataclass and NamedTuple in the package is followed by its
    docstring line: what it is, in which units and shape."""
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.ClassDef) and _is_record(node)):
                continue
            for stmt, following in zip(node.body, [*node.body[1:], None], strict=True):
                if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                    continue
                if "ClassVar" in ast.unparse(stmt.annotation):
                    continue
                documented = (
                    isinstance(following, ast.Expr)
                    and isinstance(following.value, ast.Constant)
                    and isinstance(following.value.value, str)
                )
                if not documented:
                    where = path.relative_to(PACKAGE.parent)
                    missing.append(f"{where}:{stmt.lineno} {node.name}.{stmt.target.id}")
    assert not missing, "fields without a docstring:\n" + "\n".join(missing)


def test_function_level_imports_say_why():
    """An import inside a function hides what a module depends on (and can hide a cycle):
    each is marked ``# noqa: PLC0415`` with the reason next to it (a heavy or optional
    import only some calls need)."""
    unmarked = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = path.read_text()
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for inner in ast.walk(node):
                if isinstance(inner, (ast.Import, ast.ImportFrom)):
                    if "PLC0415" not in lines[inner.lineno - 1]:
                        where = path.relative_to(PACKAGE.parent)
                        unmarked.append(f"{where}:{inner.lineno} {ast.unparse(inner)}")
    assert not unmarked, "function-level imports without a reason:\n" + "\n".join(unmarked)
