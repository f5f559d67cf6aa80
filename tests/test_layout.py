"""The package layout of docs/architecture.md: folders by role, imports only downwards,
a one-line docstring per module, no module over 600 lines; the public Python API."""
import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(__file__), "..")

#: what each part of ``parsph`` may import (besides itself, the standard library, the
#: third-party stack, ``decomposition`` and ``solvers``); bottom to top
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
    for folder in ("parsph", "solvers", "decomposition"):
        for root, _, files in os.walk(os.path.join(ROOT, folder)):
            for name in sorted(files):
                if name.endswith(".py"):
                    path = os.path.join(root, name)
                    yield os.path.relpath(path, ROOT), path


def _part(module: str) -> str | None:
    """The part of parsph a dotted module name belongs to (None outside parsph)."""
    bits = module.split(".")
    if bits[0] != "parsph":
        return None
    return bits[1] if len(bits) > 1 else "parsph"


def _imports(path):
    tree = ast.parse(open(path, encoding="utf-8").read())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "parsph":
                yield from (f"parsph.{a.name}" for a in node.names)
            else:
                yield node.module


def test_parts_import_only_downwards():
    wrong = []
    for rel, path in _modules():
        if not rel.startswith("parsph"):
            continue
        bits = rel[:-3].split(os.sep)
        part = bits[1] if len(bits) > 1 else "parsph"
        assert part in ALLOWED, f"{rel}: a part docs/architecture.md does not name"
        for target in _imports(path):
            other = _part(target)
            if other in (None, part) or other == "__version__":
                continue
            if other not in ALLOWED[part]:
                wrong.append(f"{rel} imports {target}")
    assert not wrong, "imports against docs/architecture.md:\n" + "\n".join(wrong)


def test_every_module_says_what_it_owns_and_stays_short():
    missing, long = [], []
    for rel, path in _modules():
        text = open(path, encoding="utf-8").read()
        doc = ast.get_docstring(ast.parse(text))
        if rel.endswith("__main__.py"):
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
    cheap = {"test_benchlib", "test_geometry", "test_geotiff", "test_heap", "test_layout",
             "test_loading", "test_mesh", "test_scene"}  # under a second each
    assert set(modules) - set(MODULE_SECONDS) == cheap
    load = [sum(MODULE_SECONDS.get(m, 1.0) for m in modules if deal[m] == k) for k in (0, 1)]
    assert max(load) <= 1.1 * min(load), load
