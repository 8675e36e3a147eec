"""Static rules for a codebase others can extend (checked by AST, no imports of the code under test besides the vocabulary).

* no function over 80 lines or with over 10 parameters (``self`` / ``cls`` not counted);
* no module over 800 lines, no package folder with over 15 modules (its ``__init__`` counted), no line over 120
  characters in the packages;
* no mismatch term name as a string literal in more than 2 modules of ``phast_model/mismatch``;
* no import cycle among the package's modules (module-level and function-level imports alike);
* no private name (``_name``) imported from another module of the package;
* the shared identification layer (``identify``) imports neither tool, and the world model and the trainer (with
  its rig path) import nothing from the mismatch tool (the friction curve the rig's friction plot draws lives in
  ``identify``);
* the mismatch tool's stages point one way: no stage of ``phast_model/mismatch`` imports a later one (so no two import
  each other), the shared ``options`` / ``rows`` import no stage, and only the composer (``analysis``, the package's
  ``__init__``) imports them all;
* scipy's Savitzky-Golay filter is called by the swappable differentiator only (``identify.signals``);
* no module but the term registry names the Stribeck kind: velocity grids, refinement and candidate scales are asked
  of the kind;
* the tests import the packages, never a script of ``benchmarks/`` or ``examples/`` (a test of a script's command
  line runs it as a subprocess).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

from tests import ROOT

PACKAGES = ("phast_gym", "phast_model")
MAX_FUNCTION_LINES, MAX_PARAMETERS, MAX_MODULE_LINES, MAX_TERM_MODULES = 80, 10, 800, 2
MAX_FOLDER_MODULES = 15


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the two packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()
TREES = {name: ast.parse(path.read_text(), str(path)) for name, path in MODULES.items()}


def _n_parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    names += [x.arg for x in (a.vararg, a.kwarg) if x is not None]
    return len([n for n in names if n not in ("self", "cls")])


def _functions():
    for name, tree in TREES.items():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield name, node


def test_functions_are_short_with_few_parameters():
    long = [f"{m}.{f.name}: {f.end_lineno - f.lineno + 1} lines" for m, f in _functions()
            if f.end_lineno - f.lineno + 1 > MAX_FUNCTION_LINES]
    wide = [f"{m}.{f.name}: {_n_parameters(f)} parameters" for m, f in _functions() if _n_parameters(f) > MAX_PARAMETERS]
    assert not long and not wide, "\n".join(long + wide)


#: the packages' lines wrap at this many characters (ruff's limit, 140, also covers tests, examples and benchmarks)
MAX_LINE = 120


def test_package_lines_wrap_at_120():
    wide = [f"{name}:{i}: {len(line)} characters" for name, path in MODULES.items()
            for i, line in enumerate(path.read_text().splitlines(), 1) if len(line) > MAX_LINE]
    assert not wide, "\n".join(wide)


def test_modules_are_small():
    big = [f"{name}: {len(path.read_text().splitlines())} lines" for name, path in MODULES.items()
           if len(path.read_text().splitlines()) > MAX_MODULE_LINES]
    assert not big, "\n".join(big)


def test_folders_are_small():
    """A package folder shows its parts at a glance: no more than 15 modules (subpackages group the rest)."""
    per_folder: dict[Path, int] = defaultdict(int)
    for path in MODULES.values():
        per_folder[path.parent] += 1
    big = [f"{folder.relative_to(ROOT)}: {k} modules" for folder, k in sorted(per_folder.items()) if k > MAX_FOLDER_MODULES]
    assert not big, "\n".join(big)


def _term_names() -> set[str]:
    from phast_model.mismatch.vocabulary.terms import VOCABULARY

    return {str(getattr(t, "name", t)) for t in VOCABULARY}


def test_term_names_live_in_the_registry():
    names = _term_names()
    assert len(names) >= 10, names
    where: dict[str, set[str]] = defaultdict(set)
    for module, tree in TREES.items():
        if not module.startswith("phast_model.mismatch"):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value in names:
                where[node.value].add(module)
    spread = {k: sorted(v) for k, v in where.items() if len(v) > MAX_TERM_MODULES}
    assert not spread, spread


def _imports(module: str, tree: ast.Module) -> set[str]:
    """The package modules ``module`` imports, anywhere in its body (relative imports resolved)."""
    is_pkg = MODULES[module].name == "__init__.py"
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    found = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                stem = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            targets = [f"{stem}.{a.name}" for a in node.names] + [stem]
        for t in targets:
            while t and t not in MODULES:
                t = t.rpartition(".")[0]
            if t and t != module:
                found.add(t)
    return found


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle through non-package modules, or None (a package's ``__init__`` re-exports are not edges back)."""
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(u: str) -> list[str] | None:
        colour[u] = 1
        stack.append(u)
        for v in sorted(graph[u]):
            if colour.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in colour and (found := visit(v)):
                return found
        stack.pop()
        colour[u] = 2
        return None

    for u in sorted(graph):
        if u not in colour and (found := visit(u)):
            return found
    return None


def test_no_import_cycle():
    packages = {m for m, p in MODULES.items() if p.name == "__init__.py"}
    graph = {m: {t for t in _imports(m, tree) if t not in packages} for m, tree in TREES.items() if m not in packages}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def test_no_private_name_crosses_a_module():
    crossing = [f"{module}: from {node.module} import {a.name}" for module, tree in TREES.items() for node in ast.walk(tree)
                if isinstance(node, ast.ImportFrom) and node.module != "__future__"
                for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not crossing, "\n".join(crossing)


#: (importing package, package it must not import): no exceptions
LAYER_RULES = (("phast_model.identify", "phast_model.mismatch"), ("phast_model.identify", "phast_model.world"),
               ("phast_model.identify", "phast_model.train"), ("phast_model.world", "phast_model.mismatch"),
               ("phast_model.train", "phast_model.mismatch"))


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def test_layers_point_one_way():
    broken = [f"{m} imports {t}" for m, tree in TREES.items() for t in sorted(_imports(m, tree))
              for src, banned in LAYER_RULES
              if _inside(m, src) and _inside(t, banned)]
    assert not broken, "\n".join(broken)


#: the mismatch tool's stages in the order they may import one another (a stage imports only earlier ones), each with
#: its modules and folders under ``phast_model.mismatch``: the prepared fitting problem is fitted in the vocabulary's
#: model family, the held-out scoring is set up on it, the calibration and the selection fit it, the explainers'
#: interface carries the selection's result, the friction stage answers through that interface, and the report (with
#: the MJCF answer) reads every answer
MISMATCH = "phast_model.mismatch"
MISMATCH_STAGES = (("vocabulary",), ("fitting",), ("evaluate", "energy", "written"), ("calibrate",), ("selection",), ("explainers",),
                   ("friction",), ("locate",), ("report",))
#: imported by any stage, importing none
MISMATCH_SHARED = ("options", "rows")
#: composes the stages (the only modules that may import every stage)
MISMATCH_COMPOSER = ("analysis", "")


def _mismatch_part(module: str) -> str | None:
    """The stage, shared module or composer of a module of the mismatch tool: its first name under the package."""
    if not _inside(module, MISMATCH):
        return None
    return module[len(MISMATCH):].lstrip(".").split(".")[0]


def _stage_of() -> dict[str, int]:
    return {name: i for i, names in enumerate(MISMATCH_STAGES) for name in names}


def test_mismatch_stages_point_one_way():
    """``phast_model/mismatch`` is stages with interfaces, composed in one place (``analysis``): no stage imports a
    later one or the composer, and every module has its place in :data:`MISMATCH_STAGES` (a new one is placed there)."""
    stage = _stage_of()
    parts = {m: _mismatch_part(m) for m in MODULES if _inside(m, MISMATCH)}
    unplaced = sorted(m for m, part in parts.items() if part not in stage and part not in MISMATCH_SHARED + MISMATCH_COMPOSER)
    empty = sorted(name for name in stage if not any(part == name for part in parts.values()))
    broken = []
    for m, part in parts.items():
        for t in sorted(_imports(m, TREES[m])):
            target = _mismatch_part(t)
            if target is None or target == part or part in MISMATCH_COMPOSER:
                continue
            if target in MISMATCH_COMPOSER:
                broken.append(f"{m} imports the composer {t}")
            elif part in MISMATCH_SHARED and target not in MISMATCH_SHARED:
                broken.append(f"{m} (shared) imports the stage {t}")
            elif target in stage and part in stage and stage[target] > stage[part]:
                broken.append(f"{m} (stage {part}) imports the later stage {t}")
    assert not unplaced and not empty and not broken, "\n".join(
        [f"not in MISMATCH_STAGES: {m}" for m in unplaced] + [f"stage without a module: {n}" for n in empty] + broken)


def _names(tree: ast.Module) -> set[str]:
    """Every name a module uses or imports (identifiers, attributes, imported names)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.alias):
            out.add(node.name.rpartition(".")[2])
    return out


def test_one_differentiator():
    users = sorted(m for m, tree in TREES.items() if m != "phast_model.identify.signals"
                   and {"savgol_filter", "savgol_coeffs"} & _names(tree))
    assert not users, users


def test_velocity_rules_are_the_kinds():
    users = sorted(m for m, tree in TREES.items() if m != "phast_model.mismatch.vocabulary.registry"
                   and {"STRIBECK", "Stribeck"} & _names(tree))
    assert not users, users


#: what loads a file as a module, or imports a script folder (the repository root is on the path under pytest)
SCRIPT_LOADERS = {"spec_from_file_location", "module_from_spec", "SourceFileLoader", "run_path", "load_script"}
SCRIPT_FOLDERS = {"benchmarks", "examples", "repo_scripts"}


def _script_imports(tree: ast.Module) -> list[str]:
    """The lines of ``tree`` that import a script by path or a script folder as a module."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            modules = [node.module or ""] if not node.level else []
            if node.module in ("importlib.util", "importlib.machinery", "runpy"):
                modules += [f"{node.module}.{a.name}" for a in node.names if a.name in SCRIPT_LOADERS]
        elif isinstance(node, (ast.Attribute, ast.Name)):
            name = node.attr if isinstance(node, ast.Attribute) else node.id
            modules = [name] if name in SCRIPT_LOADERS else []
        else:
            modules = []
        found += [f"line {node.lineno}: {m}" for m in modules
                  if (m.split(".")[0] in SCRIPT_FOLDERS and not _benchmark_library(m))
                  or m.rpartition(".")[2] in SCRIPT_LOADERS]
    return found


def _benchmark_library(module: str) -> bool:
    """A module of ``benchmarks/`` with no ``__main__`` block: a library the benchmark scripts share (a peer
    runner), which a test may import; a script is run as a subprocess."""
    path = ROOT.joinpath(*module.split(".")).with_suffix(".py")
    return module.startswith("benchmarks.") and path.is_file() and "__main__" not in path.read_text()


def test_tests_import_the_packages_not_the_scripts():
    """The tests exercise the packages: a helper a test needs lives in phast_gym / phast_model (or is a library
    module of ``benchmarks/``, such as the sysid peer), and a script's command line is run as a subprocess
    (``python benchmarks/x.py ...``), never loaded by path."""
    offenders = [f"{path.relative_to(ROOT)} {hit}" for path in sorted((ROOT / "tests").rglob("*.py"))
                 for hit in _script_imports(ast.parse(path.read_text(), str(path)))]
    assert not offenders, "\n".join(offenders)
    assert not (ROOT / "tests" / "repo_scripts.py").exists()
