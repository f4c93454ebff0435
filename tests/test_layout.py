"""The package's layout, read with ``ast`` (the README's "Layout"): data flows downward,
nothing imports upward, no import cycle; the scene and its light live below the
renderers, the renderers hold the transport only; the light stage's functions stay
small enough to read."""

import ast
import pathlib

import pytest

import zcomp_cli

SRC = pathlib.Path(zcomp_cli.__file__).parent

# The layers, lowest first: a module may import its own layer and those below it.
# (Top-level modules not named here -- conventions, camera, imageio, ... -- are the
# foundation every layer may use; they may not import a named layer above them.)
LAYERS = [
    ("scene",),
    ("light",),
    ("renderers", "compositing", "estimators", "blender", "training"),
    ("pipeline",),
    ("metrics", "report", "datasets", "benchsuite", "preview"),
    ("cli",),
    ("__main__", "testing"),  # the entry point; the tests' scenes and helpers
]


def _module_name(path: pathlib.Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports() -> dict[str, set[str]]:
    """Every module of zcomp_cli (scripts run inside Blender left out) -> the zcomp_cli
    modules it imports, at any depth of the code (an import inside a function counts)."""
    out = {}
    for path in SRC.rglob("*.py"):
        if "blender/scripts" in path.as_posix():
            continue
        name = _module_name(path)
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found |= {a.name for a in node.names if a.name.startswith("zcomp_cli")}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                if node.module.startswith("zcomp_cli"):
                    subs = {f"{node.module}.{a.name}" for a in node.names}
                    # ``from zcomp_cli.light import fit``: the submodule, not the package
                    found |= subs if all(_is_module(x) for x in subs) else {node.module} | {
                        x for x in subs if _is_module(x)}
        out[name] = found
    modules = set(out)
    # (a module's own packages are no dependency: importing one of their modules runs them)
    return {m: {i for i in imps if i in modules and i != m and not m.startswith(i + ".")} for m, imps in out.items()}


def _is_module(dotted: str) -> bool:
    p = SRC.parent.joinpath(*dotted.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def _layer(module: str) -> int | None:
    parts = module.split(".")
    if len(parts) < 2:
        return None
    for k, names in enumerate(LAYERS):
        if parts[1] in names:
            return k
    return None


def test_nothing_imports_upward():
    bad = []
    for m, imps in _imports().items():
        lm = _layer(m)
        for i in imps:
            li = _layer(i)
            if li is None:
                continue
            if lm is None or li > lm:
                bad.append(f"{m} -> {i}")
    assert not bad, "imports climbing a layer:\n" + "\n".join(sorted(bad))


def test_no_import_cycle():
    """No cycle among the modules (an import inside a function counts: it is one
    all the same), nor among the packages (pipeline and blender included)."""
    graph = _imports()

    def cycle(g):
        colour, stack = {}, []

        def visit(n):
            colour[n] = 1
            stack.append(n)
            for m in sorted(g.get(n, ())):
                if colour.get(m) == 1:
                    return stack[stack.index(m):] + [m]
                if colour.get(m) is None:
                    c = visit(m)
                    if c:
                        return c
            colour[n] = 2
            stack.pop()
            return None

        for n in sorted(g):
            if colour.get(n) is None:
                c = visit(n)
                if c:
                    return c
        return None

    c = cycle(graph)
    assert c is None, "import cycle: " + " -> ".join(c)

    def package(m):
        parts = m.split(".")
        return ".".join(parts[:2]) if len(parts) > 2 or (SRC / parts[-1]).is_dir() else m

    packages: dict[str, set[str]] = {}
    for m, imps in graph.items():
        packages.setdefault(package(m), set()).update(package(i) for i in imps if package(i) != package(m))
    c = cycle(packages)
    assert c is None, "package cycle: " + " -> ".join(c)


def test_the_renderers_hold_the_transport_only():
    graph = _imports()
    cycles_to_physical = sorted(f"{m} -> {i}" for m, imps in graph.items() if m.startswith("zcomp_cli.renderers.cycles")
                                for i in imps if i.startswith("zcomp_cli.renderers.physical"))
    assert not cycles_to_physical, cycles_to_physical
    lines = sum(len(p.read_text().splitlines()) for p in (SRC / "renderers").rglob("*.py"))
    assert lines < 4000, f"renderers/ holds {lines} lines"


def _decision_points(fn: ast.AST) -> int:
    n = 0
    for node in ast.walk(fn):
        if isinstance(node, (ast.If, ast.For, ast.While, ast.IfExp, ast.ExceptHandler, ast.With, ast.Assert,
                             ast.comprehension)):
            n += 1
        elif isinstance(node, ast.BoolOp):
            n += len(node.values) - 1
    return n


@pytest.mark.parametrize("package", ["light", "scene"])
def test_no_function_of_the_light_stage_too_large(package):
    big = []
    for path in sorted((SRC / package).glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                points = _decision_points(node)
                if package == "light" and (length > 120 or points > 40):
                    big.append(f"{path.stem}.{node.name}: {length} lines, {points} decision points")
    assert not big, big
