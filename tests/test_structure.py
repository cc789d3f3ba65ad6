"""The house's rules, read from the code's imports (see docs/layout.md).

Layers run one way: ``contracts`` (typed contracts, at the bottom) <- ``client`` (the HTTP client, on nothing
but ``contracts``) and ``geoloc`` (the method) <- ``db`` <- ``workers`` <- ``service`` <- ``cli``; the tools
sit on top: ``testbed`` (the servers tests and benchmarks start) <- ``benchmarks`` <- ``research`` <- ``tests``.
Inside ``geoloc`` the runtime stages (``core`` <- ``photos``, ``maps`` <- ``vision`` <- ``localize``) never
import the simulator, the evaluation or the model export, and none of the method reads the settings; the
runtime never imports the client. The API's models are defined once, in ``contracts.api``. No import circle
anywhere; no module over 450 lines outside tests; no public function outside tests over 10 parameters (Typer
commands excepted); a project module imported inside a function says why in a comment (on its line, or above the
run of imports it belongs to).
"""

from __future__ import annotations

import ast
import graphlib
import importlib
import sys
import warnings
from collections import defaultdict
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = (
    "contracts",
    "client",
    "geoloc",
    "db",
    "workers",
    "service",
    "cli",
    "testbed",
    "benchmarks",
    "research",
    "tests",
)
LAYERS = {name: rank for rank, name in enumerate(PACKAGES)}
"""Each top-level package's layer: a module may import only its own layer or lower ones."""
GEOLOC_LAYERS = {"core": 0, "photos": 1, "maps": 1, "vision": 2, "localize": 3, "sim": 4, "evaluation": 5}
"""The method's packages: the runtime stages (up to ``localize``) below the simulator and the evaluation."""
OFF_RUNTIME = ("geoloc.sim", "geoloc.evaluation", "geoloc.export", "client")
"""What the runtime never imports: the simulator, the evaluation, the model export (PyTorch) and the HTTP client
(httpx; it talks to the service, for the CLI, the benchmarks and users' scripts)."""
DEPRECATED = ("geoloc.client",)
"""Aliases kept for one release that no project module imports (``geoloc.client``: the :mod:`client` package)."""
API_MODEL_PACKAGES = ("contracts", "client", "service")
"""Where the API's models could be declared; each pydantic model name is defined once across them."""
MAX_MODULE_LINES = 450
REFERENCE_SUFFIX = "_reference"
"""A compiled kernel's numpy specification lives in a module named so, beside its twin; the runtime never imports it."""


@dataclass(frozen=True)
class Import:
    """One import of a project module: who imports what, where, and whether inside a function."""

    importer: str
    imported: str
    line: int
    in_function: bool
    explained: bool


@cache
def modules() -> dict[str, Path]:
    """Every project module by its dotted name."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _resolve(name: str) -> str | None:
    """The project module a dotted import name refers to (a module, or a name inside one)."""
    while name and name not in modules():
        name = name.rpartition(".")[0]
    return name or None


@cache
def imports() -> tuple[Import, ...]:
    """Every import of a project module, from every project module (``TYPE_CHECKING`` blocks included)."""
    return tuple(edge for module, path in modules().items() for edge in _module_imports(module, path))


def _module_imports(module: str, path: Path) -> list[Import]:
    """The imports of project modules in one module, each with where it stands and whether it says why."""
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source)
    block_start = _import_block_starts(tree)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[Import] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [alias.name for alias in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = package.split(".")[: len(package.split(".")) - (child.level - 1)]
                    base = ".".join([*anchor, *([child.module] if child.module else [])])
                names = [f"{base}.{alias.name}" for alias in child.names] + [base]
            targets = {_resolve(name) for name in names} - {None, module}
            if not targets:
                visit(child, inside)
                continue
            line = getattr(child, "lineno", 0)
            own_lines = lines[line - 1 : getattr(child, "end_lineno", line)]
            run_above = lines[max(block_start.get(line, line) - 2, 0) : line - 1]  # from the line above its run
            explained = any("#" in text for text in own_lines) or any(t.strip().startswith("#") for t in run_above)
            found.extend(Import(module, t, line, in_function, explained) for t in sorted(filter(None, targets)))
            visit(child, inside)

    visit(tree, False)
    return found


def _import_block_starts(tree: ast.Module) -> dict[int, int]:
    """For each import statement's line, the first line of the run of consecutive imports it belongs to.

    A comment above such a run explains every import in it (``# lazy: ...`` once for a command's imports).
    """
    starts: dict[int, int] = {}
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            statements = getattr(node, field, None)
            if not isinstance(statements, list):
                continue
            first: int | None = None
            for statement in statements:
                if isinstance(statement, ast.Import | ast.ImportFrom):
                    first = statement.lineno if first is None else first
                    starts[statement.lineno] = first
                else:
                    first = None
    return starts


def _cycle() -> list[str]:
    """One import circle (modules, the first repeated at the end), or an empty list when there is none."""
    graph: dict[str, set[str]] = {module: set() for module in modules()}
    for edge in imports():
        graph[edge.importer].add(edge.imported)
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as error:
        return list(error.args[1])
    return []


def test_no_import_circle() -> None:
    assert _cycle() == []


def test_layers_run_one_way() -> None:
    upward = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if LAYERS[edge.imported.split(".")[0]] > LAYERS[edge.importer.split(".")[0]]
    ]
    assert upward == []


def test_the_method_runs_one_way_and_the_runtime_never_imports_the_tools() -> None:
    wrong = []
    for edge in imports():
        importer, imported = edge.importer.split("."), edge.imported.split(".")
        if importer[0] != "geoloc" or imported[0] != "geoloc" or len(importer) < 2 or len(imported) < 2:
            continue
        if importer[1] == "export" or importer[1] == imported[1]:
            continue
        if imported[1] == "export" or GEOLOC_LAYERS[imported[1]] >= GEOLOC_LAYERS[importer[1]]:
            wrong.append(f"{edge.importer}:{edge.line} imports {edge.imported}")
    assert wrong == []


def test_runtime_layers_never_import_the_tools() -> None:
    """Nor a compiled kernel's numpy specification (a ``*_reference`` module: the tests and benchmarks' only)."""
    runtime = ("contracts", "geoloc.core", "geoloc.photos", "geoloc.maps", "geoloc.vision", "geoloc.localize")
    runtime += ("db", "workers", "service")
    wrong = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if edge.importer.startswith(runtime)
        and (edge.imported.startswith(OFF_RUNTIME) or edge.imported.endswith(REFERENCE_SUFFIX))
    ]
    assert wrong == []


def test_contracts_import_no_project_package_and_the_method_reads_no_settings() -> None:
    wrong = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if (edge.importer.startswith("contracts") and not edge.imported.startswith("contracts"))
        or (edge.importer.startswith("geoloc.") and edge.imported == "contracts.settings")
        and not edge.importer.startswith(("geoloc.export", "geoloc.evaluation"))
    ]
    assert wrong == []


def test_function_level_imports_say_why() -> None:
    silent = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if edge.in_function and not edge.explained and not edge.importer.startswith("tests")
    ]
    assert silent == []


@pytest.mark.parametrize("package", [p for p in PACKAGES if p != "tests"])
def test_no_module_over_the_size_limit(package: str) -> None:
    too_long = {
        module: n
        for module, path in modules().items()
        if module.split(".")[0] == package and (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES
    }
    assert too_long == {}


def test_the_client_imports_only_contracts() -> None:
    wrong = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if edge.importer.split(".")[0] == "client" and edge.imported.split(".")[0] not in ("client", "contracts")
    ]
    assert wrong == []


def test_no_module_imports_a_deprecated_alias() -> None:
    wrong = [
        f"{edge.importer}:{edge.line} imports {edge.imported}"
        for edge in imports()
        if edge.imported.startswith(DEPRECATED) and not edge.importer.startswith(DEPRECATED)
    ]
    assert wrong == []


def _pydantic_models(package: str) -> list[tuple[str, str]]:
    """(class name, module) of every pydantic model a package defines (subclasses of subclasses included)."""
    classes = [
        (node, module)
        for module, path in modules().items()
        if module.split(".")[0] == package
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, ast.ClassDef)
    ]
    models, found = {"BaseModel", "ApiModel", "_Answer"}, True
    while found:  # a class is a model when one of its bases is: grow the set until it stops
        found = False
        for node, _ in classes:
            bases = {base.attr if isinstance(base, ast.Attribute) else getattr(base, "id", "") for base in node.bases}
            if node.name not in models and bases & models:
                models.add(node.name)
                found = True
    return [(node.name, module) for node, module in classes if node.name in models]


def test_the_api_models_are_defined_once() -> None:
    """One pydantic class per name across contracts, client and service; the client and the service define none."""
    defined: dict[str, list[str]] = defaultdict(list)
    for package in API_MODEL_PACKAGES:
        for name, module in _pydantic_models(package):
            defined[name].append(module)
    assert {name: where for name, where in defined.items() if len(where) > 1} == {}
    outside = {name: where for name, where in defined.items() if not where[0].startswith("contracts.")}
    assert outside == {}, "the API's models belong in contracts.api"


def test_geoloc_client_is_a_deprecated_alias_of_client() -> None:
    import client
    import client.models

    for name in [name for name in sys.modules if name == "geoloc.client" or name.startswith("geoloc.client.")]:
        del sys.modules[name]
    with pytest.warns(DeprecationWarning, match="import client instead"):
        alias = importlib.import_module("geoloc.client")
    assert alias is client
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once, at the first import
        models = importlib.import_module("geoloc.client.models")
    assert models is client.models
    assert (alias.Client, alias.ApiError, models.Map) == (client.Client, client.ApiError, client.models.Map)


VENDORED_SCRIPTS: frozenset[str] = frozenset()
"""Third-party JavaScript kept as shipped, left out of the size rule (none: the viewer vendors nothing)."""
SCRIPT_IMPORT = r"^import\b[^;]*?\bfrom\s+[\"']\./([\w.-]+\.js)[\"']"
"""An ES module's import of a sibling module (the viewer's modules import each other as ``./name.js``)."""


@cache
def scripts() -> dict[str, str]:
    """The project's JavaScript (tracked, or new and not ignored) by repository path, with its text."""
    import subprocess  # only the JavaScript rules list files through git

    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z", "--", "*.js"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split("\0")
    return {path: (ROOT / path).read_text() for path in sorted(filter(None, listed)) if (ROOT / path).is_file()}


def test_no_javascript_file_over_the_size_limit() -> None:
    assert any(path.startswith("service/viewer/") for path in scripts()), "the viewer's modules are not found"
    too_long = {
        path: n
        for path, text in scripts().items()
        if path not in VENDORED_SCRIPTS and (n := len(text.splitlines())) > MAX_MODULE_LINES
    }
    assert too_long == {}


def test_the_viewer_modules_import_no_circle() -> None:
    """The viewer's modules by concern run one way: the panels over the page's shared parts over the map view."""
    import re  # only this rule reads JavaScript imports

    graph: dict[str, set[str]] = {}
    for path, text in scripts().items():
        folder = path.rpartition("/")[0]
        graph[path] = {f"{folder}/{name}" for name in re.findall(SCRIPT_IMPORT, text, re.M)}
    unknown = {f"{path} imports {target}" for path, targets in graph.items() for target in targets - graph.keys()}
    assert unknown == set()
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as error:
        pytest.fail(f"import circle: {error.args[1]}")


MAX_PUBLIC_PARAMETERS = 10
PARAMETER_RULE_PACKAGES = (
    "contracts", "geoloc", "db", "workers", "service", "cli", "client", "testbed", "benchmarks", "research",
)  # fmt: skip


def _is_command_call(node: ast.expr) -> bool:
    """Whether ``node`` is ``something.command(...)`` (Typer's decorator, called)."""
    return isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "command"


@cache
def _cli_commands() -> frozenset[str]:
    """Every ``cli`` function declared a Typer command, as ``module.function``.

    Decorated ``@app.command(...)``, or registered ``app.command(...)(function)`` (or ``(module_alias.function)``,
    through ``from cli import module as module_alias``).
    """
    found = set()
    for module, path in modules().items():
        if module.split(".")[0] != "cli":
            continue
        tree = ast.parse(path.read_text())
        aliases = {
            alias.asname or alias.name: f"{node.module}.{alias.name}"
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module
            for alias in node.names
        }
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                if any(_is_command_call(decorator) for decorator in node.decorator_list):
                    found.add(f"{module}.{node.name}")
            elif isinstance(node, ast.Call) and _is_command_call(node.func) and len(node.args) == 1:
                target = node.args[0]
                if isinstance(target, ast.Name):
                    found.add(f"{module}.{target.id}")
                elif isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name):
                    found.add(f"{aliases.get(target.value.id, target.value.id)}.{target.attr}")
    return frozenset(found)


def _public_functions(path: Path) -> list[tuple[str, int, int]]:
    """(name, line, parameter count) of every public function or method of a module (``self``/``cls`` not counted)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not node.name.startswith("_"):
            arguments = node.args
            names = [a.arg for a in (*arguments.posonlyargs, *arguments.args, *arguments.kwonlyargs)]
            if names[:1] in (["self"], ["cls"]):
                names = names[1:]
            found.append((node.name, node.lineno, len(names)))
    return found


def test_no_public_function_takes_more_than_ten_parameters() -> None:
    """No public function (name not starting with ``_``) takes over 10 parameters, positional and keyword-only.

    Checked in every package but the tests; past ten, the parameters belong in a typed record or options object
    (:class:`db.records.NewReference`, :class:`cli.ingest.IngestOptions`, a route's form read by a dependency).
    Excepted by rule: Typer commands (decorated ``@app.command(...)`` or registered ``app.command(...)(function)``;
    Typer declares one command-line option per parameter, and the command builds the options object it passes
    on).
    """
    commands = _cli_commands()
    over = [
        f"{module}.{name} (line {line}): {count} parameters"
        for module, path in modules().items()
        if module.split(".")[0] in PARAMETER_RULE_PACKAGES
        for name, line, count in _public_functions(path)
        if count > MAX_PUBLIC_PARAMETERS and f"{module}.{name}" not in commands
    ]
    assert not over, "take a typed record or options object instead:\n" + "\n".join(over)


def test_no_route_module_imports_another_route_module() -> None:
    """A route module (``service/routes_*.py``) imports no other route module, and no use-case imports one.

    What routes share is a use-case (``service/intake_*.py``) or a helper module: routes call them, never the
    reverse.
    """

    def is_route(module: str) -> bool:
        return module.startswith("service.routes_")

    crossing = [
        f"{edge.importer} imports {edge.imported} (line {edge.line})"
        for edge in imports()
        if is_route(edge.importer) and is_route(edge.imported) and edge.importer != edge.imported
    ]
    assert not crossing, "\n".join(crossing)
    use_cases = [module for module in modules() if module.startswith("service.intake")]
    calls_back = [
        f"{edge.importer} imports {edge.imported}"
        for edge in imports()
        if edge.importer in use_cases and is_route(edge.imported)
    ]
    assert not calls_back, "a use-case must not import a route module:\n" + "\n".join(calls_back)
