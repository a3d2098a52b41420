"""The layers of d4rt import only downwards (docs/architecture.md): parsed from the source with ast, so a
function-level import counts as much as a module-level one."""

from __future__ import annotations

import ast
from pathlib import Path

import d4rt

PACKAGE = Path(d4rt.__file__).parent

# What each part of d4rt may import from the others (written once, here; docs/architecture.md draws it).
# Lowest first: foundation, then the two engines (the model, the synthetic ground truth), the recipes
# over any answerer, drawing, files, then the users of all of them: evaluation, training, speed and
# memory measurement (d4rt bench) and the CLI.
FOUNDATION = {"errors", "config", "devices", "progress", "geometry", "disk_array", "allocator"}
ALLOWED = {
    "errors": set(),
    "progress": set(),
    "disk_array": set(),
    "allocator": set(),
    "config": {"errors"},
    "devices": {"errors"},
    "geometry": {"errors"},
    "model": FOUNDATION,
    "synthetic": FOUNDATION,
    "reconstruction": FOUNDATION,
    "viz": FOUNDATION,
    "data": FOUNDATION | {"synthetic"},
    "io": FOUNDATION | {"reconstruction", "viz"},
    "evaluation": FOUNDATION | {"model", "synthetic", "reconstruction", "io"},
    "training": FOUNDATION | {"model", "synthetic", "data", "reconstruction", "evaluation"},
    "speed": FOUNDATION | {"model", "synthetic", "reconstruction", "evaluation"},
    "cli": FOUNDATION | {"model", "synthetic", "data", "reconstruction", "viz", "io", "evaluation", "training",
                         "speed"},
    "__main__": {"cli"},
}

# The shortcuts outside code relies on (issue 4's fixed interface: ``model.reconstruct(video)`` and
# ``clip.reconstruction()`` return a Reconstruction). Each reaches one layer up from inside a method, and
# only to ``Reconstruction``; nothing else may.
SHORTCUTS = {("model/d4rt.py", "d4rt.reconstruction"), ("synthetic/clip.py", "d4rt.reconstruction")}


def d4rt_imports(path: Path) -> list[tuple[str, bool]]:
    """(imported d4rt module, at module level?) for every import of ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    top = set(map(id, tree.body))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "d4rt":
            names = [f"d4rt.{a.name}" for a in node.names]  # from d4rt import devices, __version__
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found += [(n, id(node) in top) for n in names if n == "d4rt" or n.startswith("d4rt.")]
    return found


def part_of(path: Path) -> str:
    return path.relative_to(PACKAGE).parts[0].removesuffix(".py")


def test_every_part_of_d4rt_has_a_place_in_the_layers():
    parts = {part_of(p) for p in PACKAGE.rglob("*.py") if p.parent != PACKAGE or p.name != "__init__.py"}
    assert parts <= set(ALLOWED), f"add {sorted(parts - set(ALLOWED))} to ALLOWED (and docs/architecture.md)"


def test_no_part_imports_a_layer_above_it():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "__init__.py":  # the package's face: lazy names of every layer
            continue
        part, rel = part_of(path), path.relative_to(PACKAGE).as_posix()
        for module, at_top in d4rt_imports(path):
            target = module.split(".")[1] if "." in module else "d4rt"
            if target in (part, "__version__"):
                continue
            if target not in ALLOWED[part]:
                if (rel, module) in SHORTCUTS and not at_top:
                    continue
                wrong.append(f"{rel} imports {module}")
    assert not wrong, "imports against the layers (docs/architecture.md):\n" + "\n".join(wrong)


def test_the_allowed_directions_have_no_cycle():
    state: dict[str, int] = {}

    def visit(node: str, trail: tuple[str, ...]) -> None:
        if state.get(node) == 1:
            raise AssertionError(f"cycle: {' -> '.join(trail + (node,))}")
        if state.get(node) == 2:
            return
        state[node] = 1
        for nxt in sorted(ALLOWED[node]):
            visit(nxt, trail + (node,))
        state[node] = 2

    for node in ALLOWED:
        visit(node, ())


def test_a_layer_violation_is_found(tmp_path):
    """The parser sees imports inside functions too (a lazy upward import is still an upward import)."""
    bad = tmp_path / "bad.py"
    bad.write_text("import numpy\nfrom d4rt import devices\n\ndef f():\n    from d4rt.cli import main\n    import d4rt.io.exports\n")
    assert sorted(d4rt_imports(bad)) == [("d4rt.cli", False), ("d4rt.devices", True), ("d4rt.io.exports", False)]
