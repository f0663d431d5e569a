"""Rules that keep the package's shape (issue 42 item 4), checked on the source, not by importing it.

- Family vocabulary lives in the registry: no module outside ``handx_jax/families/`` compares a value
  to a registered family's name (``fam == "ar"``, ``name in ("diffusion", …)``, ``match … case "ar"``).
  Shared code asks the registry entry (``families.entry(name)``) what a family declares instead.
- The import graph of ``handx_jax``, ``sweeps`` and ``analysis`` has no cycle, counting imports inside
  functions too (only ``if TYPE_CHECKING:`` blocks are left out: they never run).
- Rooms stay small: a module of more than ``MAX_LINES`` lines says in its docstring why it is one concern
  (a sentence starting "One concern:"), or it is split.
- Arrows point down (issue 51 item 6): the rooms the models are built on (``dataset``, ``synthesis``,
  ``annotation``, ``representation``, ``evaluation``) import neither the family registry (``families``) nor
  the command layer (``commands``), and ``evaluation`` not the packaged yardstick (``standard``) either: what
  they need from above is passed down to them. ``infra`` imports nothing of the package but ``infra``.
"""

from __future__ import annotations

import ast
from pathlib import Path

from handx_jax.families import names

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("handx_jax", "sweeps", "analysis")
REGISTRY_HOME = ROOT / "handx_jax" / "families"


def sources():
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            yield f


def module_name(f: Path) -> str:
    parts = f.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


# ---------------------------------------------------------------------------- family names


def _strings(node) -> list[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return [s for e in node.elts for s in _strings(e)]
    return []


def family_comparisons(tree: ast.AST, families: set[str]) -> list[tuple[int, str]]:
    """(line, name) of every comparison of a value with a family name in ``tree``."""
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Compare):
            for side in (n.left, *n.comparators):
                out += [(n.lineno, s) for s in _strings(side) if s in families]
        elif isinstance(n, ast.match_case):
            out += [(n.pattern.lineno, s) for p in ast.walk(n.pattern) if isinstance(p, ast.MatchValue)
                    for s in _strings(p.value) if s in families]
    return out


def test_no_module_outside_the_families_compares_with_a_family_name():
    families = set(names())
    found = [f"{f.relative_to(ROOT)}:{line}: compares with {name!r}"
             for f in sources() if REGISTRY_HOME not in f.parents
             for line, name in family_comparisons(ast.parse(f.read_text()), families)]
    assert found == [], "ask the registry entry (families.entry) instead:\n" + "\n".join(found)


def test_the_family_name_check_finds_comparisons():
    src = ('if cfg["family"] == "ar": pass\n'
           'ok = fam in ("diffusion", "other")\n'
           'match kind:\n    case "tokenizer": pass\n'
           'x = {"tokenizer": 1}["tokenizer"]  # a key, not a comparison\n')
    assert family_comparisons(ast.parse(src), {"ar", "diffusion", "tokenizer"}) == [
        (1, "ar"), (2, "diffusion"), (4, "tokenizer")]


# ---------------------------------------------------------------------------- import cycles


def _runs(tree: ast.Module):
    """Every node of the module except those under ``if TYPE_CHECKING:``."""
    todo = [tree]
    while todo:
        n = todo.pop()
        if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
            todo += n.orelse
            continue
        yield n
        todo += list(ast.iter_child_nodes(n))


def import_graph(files: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """module → the package modules it imports; ``files``: module → (source, is a package)."""
    graph = {m: set() for m in files}
    for m, (src, is_pkg) in files.items():
        for n in _runs(ast.parse(src)):
            if isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            elif isinstance(n, ast.ImportFrom):
                base = n.module or ""
                if n.level:
                    here = m.split(".") if is_pkg else m.split(".")[:-1]
                    base = ".".join(here[:len(here) - n.level + 1] + ([base] if base else []))
                # `from pkg import mod` depends on the module; `from pkg import name`, on the package
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in n.names]
            else:
                continue
            graph[m] |= {t for t in targets if t in files and t != m}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_package_import_graph_has_no_cycle():
    files = {module_name(f): (f.read_text(), f.name == "__init__.py") for f in sources()}
    assert cycles(import_graph(files)) == []


def test_the_cycle_check_finds_a_cycle_through_a_function_level_import():
    files = {"p": ("", True), "p.a": ("from p.b import x\n", False),
             "p.b": ("def f():\n    from p import a\n", False),
             "p.c": ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from p.d import D\n", False),
             "p.d": ("from .c import y\n", False)}
    assert cycles(import_graph(files)) == [["p.a", "p.b"]]


# ---------------------------------------------------------------------------- room size

MAX_LINES = 500
ONE_CONCERN = "One concern:"


def long_without_reason(files: dict[str, str]) -> list[tuple[str, int]]:
    """(name, lines) of every source in ``files`` (name → text) longer than ``MAX_LINES`` lines whose module
    docstring does not say why it is one concern."""
    out = []
    for name, src in files.items():
        n = src.count("\n") + (not src.endswith("\n") and bool(src))
        if n > MAX_LINES and ONE_CONCERN not in (ast.get_docstring(ast.parse(src)) or ""):
            out.append((name, n))
    return out


def test_no_module_is_over_500_lines_unless_its_docstring_says_why_it_is_one_concern():
    found = long_without_reason({str(f.relative_to(ROOT)): f.read_text() for f in sources()})
    assert found == [], (f"split these, or say in the module docstring why each is one concern "
                         f"({ONE_CONCERN!r} …):\n" + "\n".join(f"{f}: {n} lines" for f, n in found))


def test_the_room_size_check_finds_a_long_module_without_a_reason():
    body = "x = 1\n" * MAX_LINES
    files = {"long.py": '"""Two things."""\n' + body, "reasoned.py": f'"""{ONE_CONCERN} one thing."""\n' + body,
             "short.py": '"""Two things."""\n' + body[:-6], "comment.py": f'"""Two things."""\n# {ONE_CONCERN} no\n' + body}
    assert long_without_reason(files) == [("long.py", MAX_LINES + 1), ("comment.py", MAX_LINES + 2)]


# ---------------------------------------------------------------------------- arrows point down

ABOVE = ("handx_jax.families", "handx_jax.commands")
FORBIDDEN = {"handx_jax.dataset": ABOVE, "handx_jax.synthesis": ABOVE, "handx_jax.annotation": ABOVE,
             "handx_jax.representation": ABOVE, "handx_jax.evaluation": (*ABOVE, "handx_jax.standard")}
BOTTOM = "handx_jax.infra"


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def upward_imports(files: dict[str, tuple[str, bool]]) -> list[str]:
    """``importer -> imported`` for every import (function-level ones too) against the arrows above."""
    out = []
    for m, targets in sorted(import_graph(files).items()):
        for t in sorted(targets):
            bad = [p for room, above in FORBIDDEN.items() if _within(m, room) for p in above if _within(t, p)]
            if bad or (_within(m, BOTTOM) and _within(t, "handx_jax") and not _within(t, BOTTOM)):
                out.append(f"{m} -> {t}")
    return out


def test_the_lower_rooms_import_neither_the_registry_nor_the_commands():
    files = {module_name(f): (f.read_text(), f.name == "__init__.py") for f in sources()}
    assert {room for room in (*FORBIDDEN, BOTTOM) if any(_within(m, room) for m in files)} == {*FORBIDDEN, BOTTOM}
    assert upward_imports(files) == [], "pass what a lower room needs down to it instead:\n" + "\n".join(
        upward_imports(files))


def test_the_arrow_check_finds_an_upward_import():
    files = {"handx_jax": ("", True), "handx_jax.families": ("", True), "handx_jax.commands": ("", True),
             "handx_jax.standard": ("", True), "handx_jax.skeleton": ("", False),
             "handx_jax.dataset": ("", True), "handx_jax.infra": ("", True), "handx_jax.evaluation": ("", True),
             "handx_jax.dataset.format": ("def f():\n    from handx_jax import families\n", False),
             "handx_jax.dataset.stats": ("from handx_jax import skeleton\nfrom . import format\n", False),
             "handx_jax.evaluation.scoring": ("from ..standard import x\n", False),
             "handx_jax.infra.atomic": ("from handx_jax.skeleton import J\n", False),
             "handx_jax.families.ar": ("from handx_jax.commands import fail\n", False),
             "handx_jax.commands.data": ("from handx_jax.families import entry\n", False)}
    assert upward_imports(files) == ["handx_jax.dataset.format -> handx_jax.families",
                                     "handx_jax.evaluation.scoring -> handx_jax.standard",
                                     "handx_jax.infra.atomic -> handx_jax.skeleton"]
