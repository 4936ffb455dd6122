"""The repository's layout rules, read from source (no imports of the packages).

Run ``python tests/layout_check.py`` for a report; ``tests/test_layout.py`` asserts it.

Rules:
- no import circle between the modules of one package (module-level and function-local
  imports both count);
- no arrow up: a package imports only the packages below it (``LAYERS``);
- no module imports another module's ``_private`` name, nor a ``_private`` module of
  another package;
- every source file holds at most ``MAX_LINES`` lines;
- a package's declared dependencies are exactly those it imports (an import that only an
  optional extra brings is declared in that extra; extras may also hold constraints).
"""

from __future__ import annotations

import ast
import re
import sys
from dataclasses import dataclass
from functools import cache
from importlib.metadata import packages_distributions
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 600

# Import name -> (distribution name, source folder holding it).
PACKAGES: dict[str, tuple[str, Path]] = {
    "mikasa_envs": ("mikasa-envs", ROOT / "packages/mikasa-envs/src"),
    "mikasa_wrappers": ("mikasa-wrappers", ROOT / "packages/mikasa-wrappers/src"),
    "mikasa_datasets": ("mikasa-datasets", ROOT / "packages/mikasa-datasets/src"),
    "mikasa_oracles": ("mikasa-oracles", ROOT / "packages/mikasa-oracles/src"),
    "mikasa_bench": ("mikasa-bench", ROOT / "packages/mikasa-bench/src"),
    "mikasa_robo_rl": ("mikasa-robo-rl", ROOT / "legacy/rl/src"),
    "mikasa_robo_suite": ("mikasa-robo-rl", ROOT / "legacy/rl/src"),
}

# What each package may import of the project (everything else is an arrow up or sideways).
LAYERS: dict[str, set[str]] = {
    "mikasa_envs": set(),
    "mikasa_datasets": set(),
    "mikasa_wrappers": {"mikasa_envs"},
    "mikasa_oracles": {"mikasa_envs", "mikasa_wrappers", "mikasa_datasets"},
    "mikasa_bench": {"mikasa_envs", "mikasa_wrappers", "mikasa_oracles", "mikasa_datasets"},
    "mikasa_robo_rl": {"mikasa_envs", "mikasa_wrappers", "mikasa_oracles", "mikasa_datasets"},
    "mikasa_robo_suite": {"mikasa_envs", "mikasa_wrappers", "mikasa_oracles", "mikasa_robo_rl"},
}


@dataclass(frozen=True)
class Import:
    """One import statement's target, resolved to absolute module names."""

    source: str  # importing module
    line: int
    module: str  # imported module (absolute)
    names: tuple[str, ...]  # names taken with ``from module import ...`` (empty for ``import``)


@cache
def source_files(package: str) -> dict[str, Path]:
    """Module name -> file, for every module of ``package``."""
    base = PACKAGES[package][1]
    files = {}
    for path in sorted((base / package).rglob("*.py")):
        parts = list(path.relative_to(base).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        files[".".join(parts)] = path
    return files


def _imports(module: str, path: Path) -> list[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [Import(module, node.lineno, a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = module.split(".")
                anchor = parts if is_package else parts[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                target = ".".join(anchor + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append(Import(module, node.lineno, target, tuple(a.name for a in node.names)))
    return found


@cache
def all_imports(package: str) -> list[Import]:
    """Every import in ``package`` (module level and inside functions)."""
    return [imp for mod, path in source_files(package).items() for imp in _imports(mod, path)]


def _edges(package: str) -> dict[str, set[str]]:
    modules = source_files(package)
    edges: dict[str, set[str]] = {m: set() for m in modules}
    for imp in all_imports(package):
        targets = []
        if imp.names:
            # ``from pkg import sub`` imports the submodule; other names come from ``pkg``.
            for name in imp.names:
                sub = f"{imp.module}.{name}"
                targets.append(sub if sub in modules else imp.module)
        else:
            targets.append(imp.module)
        for target in targets:
            if target in modules and target != imp.source:
                edges[imp.source].add(target)
    return edges


def import_cycles(package: str) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    edges = _edges(package)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(edges[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                group.append(top)
                if top == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    sys.setrecursionlimit(10_000)
    for node in sorted(edges):
        if node not in index:
            visit(node)
    return groups


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_imports(package: str) -> list[str]:
    """``from m import _name`` across modules, and ``_private`` modules of other packages."""
    found = []
    for imp in all_imports(package):
        top = imp.module.split(".")[0]
        where = f"{imp.source}:{imp.line}"
        submodules = source_files(top) if top in PACKAGES else {}
        for name in imp.names:
            # A private submodule of one's own package is fine; a private name is not.
            own_submodule = top == package and f"{imp.module}.{name}" in submodules
            if _is_private(name) and not own_submodule:
                found.append(f"{where} imports {name} from {imp.module}")
        if top in PACKAGES and top != package:
            if any(_is_private(p) for p in imp.module.split(".")):
                found.append(f"{where} imports the private module {imp.module}")
    return found


def upward_imports(package: str) -> list[str]:
    """Imports of project packages that ``LAYERS`` does not allow."""
    return [
        f"{imp.source}:{imp.line} imports {imp.module}"
        for imp in all_imports(package)
        if (top := imp.module.split(".")[0]) in PACKAGES
        and top != package
        and top not in LAYERS[package]
    ]


def long_files() -> list[str]:
    """Python files of the packages, the RL release and the tests over ``MAX_LINES`` lines."""
    roots = [ROOT / "packages", ROOT / "legacy", ROOT / "tests", ROOT / "benchmarks"]
    roots += [ROOT / "scripts", ROOT / "baselines"]
    found = []
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            if any(part.startswith(".") for part in path.relative_to(ROOT).parts):
                continue
            lines = len(path.read_text(encoding="utf-8").splitlines())
            if lines > MAX_LINES:
                found.append(f"{path.relative_to(ROOT)}: {lines} lines")
    return found


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared(pyproject: Path) -> tuple[set[str], dict[str, set[str]]]:
    project = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]

    def names(reqs: list[str]) -> set[str]:
        return {_normalise(re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0].strip()) for r in reqs}

    extras = {k: names(v) for k, v in project.get("optional-dependencies", {}).items()}
    return names(project.get("dependencies", [])), extras


@cache
def _installed_distributions() -> dict[str, set[str]]:
    return {top: {_normalise(d) for d in dists} for top, dists in packages_distributions().items()}


def _providers(top: str) -> set[str]:
    """The distributions that can provide import name ``top``: the installed ones, else the
    name itself (an optional dependency this environment lacks, e.g. ``lerobot``)."""
    if top in PACKAGES:
        return {PACKAGES[top][0]}
    return _installed_distributions().get(top) or {_normalise(top)}


def _third_party_or_project(top: str) -> bool:
    return bool(top) and top != "__future__" and top not in sys.stdlib_module_names


def dependency_mismatches(package: str) -> list[str]:
    """Imports whose distribution is declared neither in ``dependencies`` nor in an extra, and
    (once per distribution) required dependencies that no module of it imports. Extras may
    hold constraints on what their packages pull in, so only ``dependencies`` must be used."""
    dist, base = PACKAGES[package]
    required, extras = _declared(base.parent / "pyproject.toml")
    optional = set().union(*extras.values()) if extras else set()
    own = {p for p, (d, _) in PACKAGES.items() if d == dist}
    tops = {imp.module.split(".")[0] for imp in all_imports(package)}
    found = [
        f"{package} imports {top} ({' or '.join(sorted(_providers(top)))}) but does not declare it"
        for top in sorted(t for t in tops if _third_party_or_project(t) and t not in own)
        if not _providers(top) & (required | optional)
    ]
    if package == min(own):  # one report per distribution
        used = set()
        for member in own:
            for imp in all_imports(member):
                used |= _providers(imp.module.split(".")[0])
        found += [f"{dist} declares {d} but imports none of it" for d in sorted(required - used)]
    return found


def report() -> dict[str, list]:
    """Every rule's violations, keyed by rule."""
    return {
        "import circles": [f"{p}: {' <-> '.join(g)}" for p in PACKAGES for g in import_cycles(p)],
        "arrows up": [v for p in PACKAGES for v in upward_imports(p)],
        "private names across modules": [v for p in PACKAGES for v in private_imports(p)],
        f"files over {MAX_LINES} lines": long_files(),
        "declared dependencies != imports": [v for p in PACKAGES for v in dependency_mismatches(p)],
    }


if __name__ == "__main__":
    failed = False
    for rule, violations in report().items():
        print(f"{rule}: {len(violations)}")
        for v in violations:
            print(f"  {v}")
        failed |= bool(violations)
    sys.exit(1 if failed else 0)
