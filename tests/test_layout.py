"""The package layout of docs/architecture.md: packages and folders by role, imports only
downwards and in no cycle, mpi4py and petsc4py each in its own package, a one-line
docstring per module, no module over 600 lines; the public Python API."""
import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")

#: the import packages of the repository, bottom to top, and which of the others each may
#: import: ``base`` (errors, the heap) under everything, ``parsph`` on top
HOUSE = {"base": set(), "decomposition": {"base"}, "solvers": {"base", "decomposition"},
         "parsph": {"base", "decomposition", "solvers"}}

#: third-party packages only some modules may import (the module or package, dotted)
OWNERS = {"petsc4py": ("solvers",), "mpi4py": ("decomposition", "parsph.cli.info")}

#: what each part of ``parsph`` may import (besides itself, the standard library, the
#: third-party stack and the packages below ``parsph`` in :data:`HOUSE`); bottom to top
ALLOWED = {
    "errors": set(), "log": set(),
    "io": {"parsph", "errors"},
    "core": {"errors"},
    "scene": {"core", "errors"},
    "solid": {"core", "scene", "errors"},
    "fluid": {"core", "scene", "errors"},
    "coupling": {"core", "scene", "solid", "fluid", "errors"},
    "step": {"parsph", "core", "scene", "io", "errors", "log"},  # stages: by name, see pipeline
    "verify": {"core", "scene", "solid", "fluid", "coupling", "step", "io", "errors"},
    "maps": {"parsph", "scene", "io", "errors", "log"},
    "cli": {"parsph", "core", "scene", "step", "verify", "io", "maps", "errors", "log"},
    "__init__": {"scene", "step"}, "__main__": {"cli"},
}


def _modules():
    """``{dotted module name: path}`` of every module of the packages in :data:`HOUSE`
    (a package by its own name, ``parsph.cli`` for ``parsph/cli/__init__.py``)."""
    out = {}
    for folder in HOUSE:
        for root, _, files in os.walk(os.path.join(ROOT, folder)):
            for name in sorted(files):
                if name.endswith(".py"):
                    path = os.path.join(root, name)
                    dotted = os.path.relpath(path, ROOT)[:-3].replace(os.sep, ".")
                    out[dotted.removesuffix(".__init__")] = path
    return out


MODULES = _modules()


def _part(module: str) -> str | None:
    """The part of parsph a dotted module name belongs to (None outside parsph)."""
    bits = module.split(".")
    if bits[0] != "parsph":
        return None
    return bits[1] if len(bits) > 1 else "parsph"


def imports(source: str, module: str, is_package: bool = False, known=MODULES):
    """Every module ``source`` imports, dotted: module level and inside functions alike
    (the whole tree is walked), relative imports resolved against ``module``, and
    ``from P import x`` as ``P.x`` when that is a module of ``known``, else as ``P``."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                bits = package.split(".")
                bits = bits[:len(bits) - (node.level - 1)]
                base = ".".join(bits + ([node.module] if node.module else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                yield sub if sub in known or sub == "parsph.__version__" else base


def _imports_of(module):
    path = MODULES[module]
    return imports(open(path, encoding="utf-8").read(), module, path.endswith("__init__.py"))


def test_the_scan_sees_imports_in_functions_and_relative_ones():
    """The scan the checks below rely on: imports at any depth, relative ones resolved."""
    source = ("import numpy\n"
              "def f():\n    from mpi4py import MPI\n    if 1:\n        import petsc4py\n"
              "class C:\n    def g(self):\n        from . import heap\n"
              "        from ..errors import E\n")
    found = set(imports(source, "base.sub.mod", known={"base.sub.heap", "base.errors"}))
    assert found == {"numpy", "mpi4py", "petsc4py", "base.sub.heap", "base.errors"}
    assert "petsc4py" in set(_imports_of("solvers.petsc_env"))  # imported inside a function


def test_packages_import_only_downwards():
    """``base`` imports none of the others, ``decomposition`` only ``base``, ``solvers``
    only those two; ``parsph`` (on top) any of them."""
    wrong = []
    for module in MODULES:
        mine = module.split(".")[0]
        for target in _imports_of(module):
            other = target.split(".")[0]
            if other in HOUSE and other != mine and other not in HOUSE[mine]:
                wrong.append(f"{module} imports {target}")
    assert not wrong, "imports against docs/architecture.md:\n" + "\n".join(wrong)


def test_mpi4py_and_petsc4py_have_their_owners():
    """Only ``solvers`` imports petsc4py; only ``decomposition`` and ``parsph info``
    (the versions it prints) import mpi4py."""
    wrong = []
    for module in MODULES:
        for target in _imports_of(module):
            top = target.split(".")[0]
            owners = OWNERS.get(top, ())
            if owners and not any(module == o or module.startswith(o + ".") for o in owners):
                wrong.append(f"{module} imports {target} (only {', '.join(owners)} may)")
    assert not wrong, "\n".join(wrong)


def _cycles(graph):
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph[v]:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle():
    """No two modules of the house import each other, directly or around a loop, at
    module level or inside a function. An import of a module's own package (``import
    parsph`` in ``parsph.io.hdf5``) is no edge: Python runs every enclosing package's
    ``__init__`` before the module, so it loads nothing new."""
    graph = {}
    for module in MODULES:
        edges = set()
        for target in _imports_of(module):
            while target and target not in MODULES:  # parsph.__version__ -> parsph
                target = target.rpartition(".")[0]
            if target and target != module and not module.startswith(target + "."):
                edges.add(target)
        graph[module] = edges
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert not _cycles(graph), f"import cycles: {_cycles(graph)}"


def test_parts_import_only_downwards():
    wrong = []
    for module in MODULES:
        if _part(module) is None:
            continue
        bits = module.split(".")
        part = bits[1] if len(bits) > 1 else "__init__"
        if MODULES[module].endswith("__main__.py"):
            part = "__main__"
        assert part in ALLOWED, f"{module}: a part docs/architecture.md does not name"
        for target in _imports_of(module):
            other = _part(target)
            if other in (None, part) or other == "__version__":
                continue
            if other not in ALLOWED[part]:
                wrong.append(f"{module} imports {target}")
    assert not wrong, "imports against docs/architecture.md:\n" + "\n".join(wrong)


def test_every_module_says_what_it_owns_and_stays_short():
    missing, long = [], []
    for rel, path in sorted(MODULES.items()):
        text = open(path, encoding="utf-8").read()
        doc = ast.get_docstring(ast.parse(text))
        if path.endswith("__main__.py"):
            continue
        if not doc or not doc.splitlines()[0].strip():
            missing.append(rel)
        if text.count("\n") > 600:
            long.append(f"{rel}: {text.count(chr(10))} lines")
    assert not missing, f"modules without a docstring: {missing}"
    assert not long, f"modules over 600 lines (split by concept): {long}"


@pytest.mark.petsc
def test_public_api_runs_a_scene(mpi_tmp_path, comm):
    """``parsph.load_scene`` and ``parsph.run``, as the package docstring shows them."""
    import parsph

    scene = parsph.load_scene("hydrostatic", overrides=["run.max_steps=2"])
    summary = parsph.run(scene, out=os.path.join(mpi_tmp_path, "out"), comm=comm, progress=False)
    assert summary["steps"] == 2 and summary["particles"] > 0
    assert os.path.exists(os.path.join(mpi_tmp_path, "out", "particles.h5"))
    with pytest.raises(AttributeError):
        parsph.no_such_thing  # noqa: B018


def test_test_modules_are_dealt_to_balanced_shards():
    """The one-rank session's shards (scripts/test.sh, PARSPH_TEST_SHARD): every test
    module in exactly one shard, the same deal in every process, each module's cost
    known (a new module gets a measured figure in MODULE_SECONDS), and the two shards'
    costs within 10 % of each other."""
    from conftest import MODULE_SECONDS, shard_of_modules

    modules = sorted(name[:-3] for name in os.listdir(os.path.join(ROOT, "tests"))
                     if name.startswith("test_") and name.endswith(".py"))
    deal = shard_of_modules(modules, 2)
    assert deal == shard_of_modules(list(reversed(modules)), 2)
    assert sorted(deal) == modules and set(deal.values()) == {0, 1}
    cheap = {"test_benchlib", "test_figures", "test_geometry", "test_geotiff", "test_heap",
             "test_layout", "test_loading", "test_mesh", "test_scene"}  # under a second each
    assert set(modules) - set(MODULE_SECONDS) == cheap
    load = [sum(MODULE_SECONDS.get(m, 1.0) for m in modules if deal[m] == k) for k in (0, 1)]
    assert max(load) <= 1.1 * min(load), load
