"""The package's import rules (DESIGN.md, "Layout"), checked on the source with ``ast``.

1. No import circle among the package's modules, counting imports inside functions too; each
   stage imports only the stages below it in the data flow (:data:`ORDER`).
2. No module imports an underscore name from another module; an underscore *module* (such as
   ``voicepuppet._core`` or ``render._backend``) is imported only from inside its own package.
3. Imports of the package's own modules inside functions only in ``voicepuppet.cli`` (to keep
   ``voicepuppet --help`` fast) and the package's lazy ``__getattr__``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "python" / "voicepuppet"
PKG = "voicepuppet"
MAX_LINES = 700

#: The package's stages from the bottom up: a module imports only modules of its own stage or
#: of stages before it here. The data flow of DESIGN.md, with two stages lower than it draws
#: them: ``animation`` (the landmark-animation file format the tracker's neighbours and the
#: puppet produce) and ``synth`` (the synthetic performer, which evaluation's corpora are made of).
ORDER = ("_core", "_version", "_files", "limits", "blas", "layout", "data", "animation", "tracking", "face", "audio", "hmm",
         "trajectory", "puppet", "render", "phonemes", "synth", "evaluation", "live", "batch", "bench", "cli",
         "__init__")


def _modules() -> dict[str, Path]:
    mods = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = (PKG,) + path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


MODULES = _modules()
KNOWN = set(MODULES) | {f"{PKG}._core"}  # the compiled extension


def _resolve(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not MODULES[module].name == "__init__.py":
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str):
    """(target module, imported name or None, inside a function?) for each import of the package."""
    tree = ast.parse(MODULES[module].read_text(), str(MODULES[module]))
    inner = set()
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inner.update(id(n) for n in ast.walk(fn) if isinstance(n, (ast.Import, ast.ImportFrom)))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == PKG:
                    yield alias.name, None, id(node) in inner, node.lineno
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(module, node)
            if target.split(".")[0] != PKG:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in KNOWN:
                    yield sub, None, id(node) in inner, node.lineno
                else:
                    yield target, alias.name, id(node) in inner, node.lineno


GRAPH = {m: sorted({t for t, _, _, _ in _imports(m) if t != m and t in MODULES}) for m in MODULES}


def _cycles(graph: dict[str, list[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(graph[w])))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return out


def test_cycle_finder_finds_a_planted_circle():
    graph = {"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": ["b"], "b": []}) == []


def test_no_import_circles():
    assert _cycles(GRAPH) == []


def _stage(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_module_belongs_to_a_stage():
    assert sorted({_stage(m) for m in KNOWN} - set(ORDER)) == []


def test_stages_import_only_lower_stages():
    rank = {s: i for i, s in enumerate(ORDER)}
    bad = [f"{m} imports {t}" for m, targets in GRAPH.items() for t in targets
           if rank[_stage(t)] > rank[_stage(m)]]
    assert bad == []


def test_no_private_names_across_modules():
    bad = []
    for m in MODULES:
        for target, name, _, line in _imports(m):
            if target == m:
                continue
            if name and name.startswith("_") and not name.startswith("__"):
                bad.append(f"{MODULES[m].relative_to(ROOT)}:{line} imports {name} from {target}")
            leaf = target.rsplit(".", 1)[-1]
            if leaf.startswith("_") and not (m + ".").startswith(target.rsplit(".", 1)[0] + "."):
                bad.append(f"{MODULES[m].relative_to(ROOT)}:{line} imports the private module {target}")
    assert bad == []


def test_own_imports_inside_functions_only_in_the_command_line():
    bad = [f"{MODULES[m].relative_to(ROOT)}:{line} imports {target}"
           for m in MODULES if not (m.startswith(f"{PKG}.cli") or m == PKG)
           for target, _, inner, line in _imports(m) if inner]
    assert bad == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_size(module):
    n = len(MODULES[module].read_text().splitlines())
    assert n <= MAX_LINES, f"{module} has {n} lines: split it by subject"


def test_subpackages_list_their_public_names():
    missing = [m for m, p in MODULES.items() if p.name == "__init__.py" and m != PKG
               and "__all__" not in p.read_text()]
    assert missing == []
