"""The house's layout (issue 23), read from the source: one package per stage, the frame
at the top, no import circle, no way from the frame or the tiling back up into a stage."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from demtool.stages import STAGES

PACKAGE = Path(__file__).resolve().parents[1] / "demtool"
#: packages of shared science below the stages
SHARED = {"sensors", "maps", "imaging"}
#: the frame every stage uses (besides the CLI layer, commands/ and cli.py)
FRAME_PACKAGES = {"io", "tiling"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """Module → the demtool modules it imports (anywhere in its body), from the AST."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            for imported in names:
                if imported.split(".")[0] == "demtool":
                    target = resolve(imported)
                    if target and target != name:
                        targets.add(target)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycle_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle():
    assert cycles(import_graph()) == []


@pytest.mark.parametrize("stage", list(STAGES))
def test_every_stage_is_one_package(stage):
    folder = PACKAGE / stage
    assert (folder / "__init__.py").is_file()
    assert (folder / "params.py").is_file()
    assert (folder / "run.py").is_file()
    assert (PACKAGE / "commands" / f"{stage}.py").is_file()


def test_top_level_holds_only_the_frame():
    modules = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(modules) <= 16, modules
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert packages == set(STAGES) | SHARED | FRAME_PACKAGES | {"commands"}


def test_no_module_is_too_long():
    long = {str(p.relative_to(PACKAGE)): n for p in PACKAGE.rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 600}
    assert long == {}


def test_the_frame_and_shared_science_never_import_a_stage():
    graph = import_graph()
    below = FRAME_PACKAGES | SHARED | {p.stem for p in PACKAGE.glob("*.py")} - {"cli"}
    offenders = {}
    for module, targets in graph.items():
        top = module.split(".")[1] if "." in module else ""
        if top not in below:
            continue
        stages = sorted(t for t in targets if t.split(".")[1:2] and t.split(".")[1] in STAGES)
        if stages:
            offenders[module] = stages
    assert offenders == {}


def test_tiled_jobs_never_import_their_runner():
    graph = import_graph()
    offenders = {module: sorted(t for t in targets if t.rpartition(".")[2].startswith("run"))
                 for module, targets in graph.items()
                 if module.rpartition(".")[2].startswith("tiled")}
    assert {m: t for m, t in offenders.items() if t} == {}
