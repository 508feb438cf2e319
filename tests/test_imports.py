"""The package's import graph: no cycles, and the lower layers never import the upper
ones. Every import counts, the lazy ones inside functions too."""

import ast

from tests.conftest import ROOT

#: Layers that must not know what runs them ...
LOWER = ("rawsim.io", "rawsim.isp", "rawsim.noise", "rawsim.engine")
#: ... the pipelines, the batch layer, the public API built on them, and the CLI.
UPPER = ("rawsim.pipelines", "rawsim.run", "rawsim.api", "rawsim.dataset", "rawsim_cli")


def _modules() -> dict[str, ast.Module]:
    """Dotted module name → its parsed source, for rawsim and the CLI (``cli/`` is
    installed as ``rawsim_cli``)."""
    modules = {}
    for folder, package in (("rawsim", "rawsim"), ("cli", "rawsim_cli")):
        for path in (ROOT / folder).rglob("*.py"):
            parts = [package, *path.relative_to(ROOT / folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = ast.parse(path.read_text(), str(path))
    return modules


def _graph() -> dict[str, set[str]]:
    """Module → the rawsim modules it imports (a ``from package import name`` counts as
    an import of the submodule where ``name`` is one, else of the package)."""
    modules = _modules()

    def known(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, tree in modules.items():
        is_package = any(m.startswith(name + ".") for m in modules)
        package = name if is_package else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets.update(known(a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([base] if base else []))
                targets.update(known(f"{base}.{a.name}") for a in node.names)
        # a module's own package (its __init__) runs first anyway: not an edge
        graph[name] = {t for t in targets if t and t != name and not name.startswith(t + ".")}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_sees_every_kind_of_import():
    graph = _graph()
    assert "rawsim.run.ray_executor" in graph["rawsim.run.batch"]  # lazy, in a function
    assert "rawsim.noise.seeds" in graph["rawsim.run.batch"]  # from-import of a module
    assert "rawsim.events.kernels" in graph["rawsim.events.stream"]  # from package import module
    assert "rawsim.io.task" in graph["rawsim.io.outputs"]  # a plain import


def test_no_import_cycles():
    assert _cycles(_graph()) == []


def test_cycles_are_found():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_lower_layers_do_not_import_upper_ones():
    upward = sorted(
        f"{m} -> {t}"
        for m, targets in _graph().items()
        if m.startswith(LOWER)
        for t in targets
        if t.startswith(UPPER)
    )
    assert upward == []
