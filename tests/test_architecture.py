"""The house rules, checked on the source (fast: the AST, no numerical work).

* No import cycle among ``rotorbayes`` modules at module level (an import at the top of a
  module, run when it is imported).  Imports inside functions run later and cannot
  deadlock an import, but a circle through them still means two modules each need the
  other's idea: those are listed by :func:`function_level_cycles` and must stay within
  :data:`KNOWN_FUNCTION_LEVEL_CYCLES` (empty today).
* No module imports a private name (``_x``) from a module of another package: an idea used
  by two rooms gets a public name in the room that owns it.
* The compiled kernel is the lowest layer: no module of ``rotorbayes.kernel`` imports
  anything of rotorbayes outside it (not the model, which builds on it), at module or
  function level.
* ``cli.py`` is a thin table of commands: fewer than :data:`CLI_MAX_LINES` lines; no
  numerical library imported; from rotorbayes only exit codes and exception classes (the
  commands are reached through the table); every command's options are exactly its
  function's keyword arguments, with the same defaults.
* Commands pass typed options (:mod:`rotorbayes.commands.config`), never a namespace of
  their locals: the options of ``fit``, ``multistart``, ``sample`` and ``identify`` are
  exactly the flattened fields of their options classes, with the same defaults; each
  shared option group of the command line is exactly one options class; the function
  hands every keyword to the field of that name.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PKG = "rotorbayes"
#: cli.py has at most this many lines (a table, a parser, a log and the exit codes).
CLI_MAX_LINES = 500
#: Libraries that do numerical work: cli.py imports none of them.
NUMERICAL = (
    "numpy",
    "scipy",
    "numba",
    "matplotlib",
    "emcee",
    "arviz",
    "corner",
    "h5py",
    "dask",
    "distributed",
    "xarray",
)
#: Circles through function-level imports accepted for now (pairs of module names).
KNOWN_FUNCTION_LEVEL_CYCLES: set[frozenset[str]] = set()


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted((SRC / PKG).rglob("*.py")):
        parts = list(p.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


MODULES = _modules()


def _package(module: str) -> str:
    """The package a module belongs to (a package's ``__init__`` belongs to itself)."""
    return module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]


def _targets(module: str, node) -> list[tuple[str, str, str | None]]:
    """(local name, imported rotorbayes module, imported name or None) for each name one
    import statement brings in from rotorbayes."""
    if isinstance(node, ast.Import):
        return [
            (a.asname or a.name.split(".")[0], a.name, None)
            for a in node.names
            if a.name.split(".")[0] == PKG
        ]
    if node.level:
        base = _package(module)
        for _ in range(node.level - 1):
            base = base.rpartition(".")[0]
        target = f"{base}.{node.module}" if node.module else base
    else:
        target = node.module or ""
    if target.split(".")[0] != PKG:
        return []
    return [
        (a.asname or a.name, f"{target}.{a.name}", None)
        if f"{target}.{a.name}" in MODULES
        else (a.asname or a.name, target, a.name)
        for a in node.names
    ]


def _is_type_checking(node) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imports() -> list[tuple[str, str, str | None, str, int]]:
    """Every import among rotorbayes modules: (importer, imported module, name, level,
    line); level is "module" (runs on import) or "function"."""
    found = []

    def visit(module, node, level):
        for child in ast.iter_child_nodes(node):
            if _is_type_checking(child):
                continue
            inner = level
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                inner = "function"
            if isinstance(child, ast.Import | ast.ImportFrom):
                for _, target, name in _targets(module, child):
                    found.append((module, target, name, level, child.lineno))
            visit(module, child, inner)

    for module, path in MODULES.items():
        visit(module, ast.parse(path.read_text(encoding="utf-8")), "module")
    return found


def _cycles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        if a != b:
            graph.setdefault(a, set()).add(b)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def connect(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                connect(w)
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
            connect(v)
    return out


def module_level_cycles() -> list[list[str]]:
    return _cycles({(a, b) for a, b, _, level, _ in _imports() if level == "module"})


def function_level_cycles() -> list[list[str]]:
    """Circles that need at least one import inside a function."""
    every = _cycles({(a, b) for a, b, *_ in _imports()})
    at_top = {frozenset(c) for c in module_level_cycles()}
    return [c for c in every if frozenset(c) not in at_top]


def test_the_scan_sees_the_package():
    # A scan that found nothing would pass everything: check it sees known imports.
    found = {(a, b, level) for a, b, _, level, _ in _imports()}
    assert len(MODULES) > 40
    assert ("rotorbayes.model.parameters", "rotorbayes.model.effects", "module") in found
    assert ("rotorbayes.commands.demo", "rotorbayes.commands.study.analysis", "function") in found
    assert _cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]


def test_no_import_cycle_at_module_level():
    cycles = module_level_cycles()
    assert not cycles, "import cycles at module level: " + "; ".join(
        " <-> ".join(c) for c in cycles
    )


def test_no_new_import_circle_through_function_level_imports():
    cycles = [c for c in function_level_cycles() if frozenset(c) not in KNOWN_FUNCTION_LEVEL_CYCLES]
    assert not cycles, (
        "modules that import each other (at least one import inside a function): "
        + "; ".join(" <-> ".join(c) for c in cycles)
        + ". Move the shared idea into the module that owns it."
    )


def test_no_private_name_imported_across_packages():
    bad = []
    for module, target, name, _, line in _imports():
        if (
            name
            and name.startswith("_")
            and not name.startswith("__")
            and _package(module) != _package(target)
        ):
            bad.append(f"{MODULES[module].relative_to(SRC)}:{line} imports {name} from {target}")
    # Private attributes of an imported module (``import x as m; m._y``).
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                for local, target, name in _targets(module, node):
                    if name is None and target in MODULES:
                        aliases[local] = target
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and _package(aliases[node.value.id]) != _package(module)
            ):
                bad.append(
                    f"{path.relative_to(SRC)}:{node.lineno} uses "
                    f"{aliases[node.value.id]}.{node.attr}"
                )
    assert not bad, "private names used across packages:\n" + "\n".join(bad)


#: The lowest layer: its modules import nothing of rotorbayes outside it.
LOWEST_LAYER = f"{PKG}.kernel"


def imports_out_of_lowest_layer(imports) -> list[str]:
    """``"importer:line imports target"`` for each import, among ``imports`` (as
    :func:`_imports` lists them), by a module of :data:`LOWEST_LAYER` of a rotorbayes
    module outside it."""

    def inside(module):
        return module == LOWEST_LAYER or module.startswith(LOWEST_LAYER + ".")

    return list(
        dict.fromkeys(  # one line per import statement, in order
            f"{importer}:{line} imports {target}"
            for importer, target, _, _, line in imports
            if inside(importer) and not inside(target)
        )
    )


def test_the_kernel_imports_nothing_above_it():
    bad = imports_out_of_lowest_layer(_imports())
    assert not bad, (
        "the compiled kernel imports from the layers above it (move what it "
        "needs into rotorbayes.kernel):\n" + "\n".join(bad)
    )


def test_the_layer_check_sees_a_kernel_module_importing_the_model():
    # What the check above would report if kernel/terms.py imported the model's friction
    # laws again (at module level) or the model's parameters inside a function.
    imports = [
        ("rotorbayes.kernel.terms", "rotorbayes.model.friction", "slip_torque", "module", 31),
        ("rotorbayes.kernel.solver", "rotorbayes.model", None, "function", 7),
        ("rotorbayes.kernel.solver", "rotorbayes.kernel.terms", "rhs", "module", 5),
        ("rotorbayes.model.friction", "rotorbayes.kernel.friction", "stribeck", "module", 3),
    ]
    assert imports_out_of_lowest_layer(imports) == [
        "rotorbayes.kernel.terms:31 imports rotorbayes.model.friction",
        "rotorbayes.kernel.solver:7 imports rotorbayes.model",
    ]
    found = {(a, b) for a, b, *_ in _imports()}
    assert ("rotorbayes.model.friction", "rotorbayes.kernel.friction") in found


# ----------------------------------------------------------------------- a thin cli.py
CLI = SRC / PKG / "cli.py"


def test_cli_is_short_and_does_no_numerical_work():
    text = CLI.read_text(encoding="utf-8")
    n = len(text.splitlines())
    assert n < CLI_MAX_LINES, f"cli.py has {n} lines; move work into rotorbayes.commands"
    tree = ast.parse(text)
    from rotorbayes import cli

    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
            )
            for name in names:
                assert name.split(".")[0] not in NUMERICAL, f"cli.py imports {name}"
        if isinstance(node, ast.ImportFrom) and node.level and node.module:
            # From rotorbayes: exception classes only (and the modules of exit codes and of
            # the first compile).
            source = importlib.import_module(f"{PKG}.{node.module}")
            for a in node.names:
                obj = getattr(source, a.name)
                if a.name == "__version__" or getattr(obj, "__name__", "") in (
                    f"{PKG}.util.exitcodes",
                    f"{PKG}.util.coldstart",
                ):
                    continue
                assert isinstance(obj, type) and issubclass(obj, BaseException), (
                    f"cli.py imports {a.name} from rotorbayes.{node.module}: only exception "
                    "classes belong here; the work is in rotorbayes.commands"
                )
    assert set(cli.COMMANDS) == {a.dest for a in _subparsers(cli.build_parser())[0]}


def _subparsers(parser) -> tuple[list, dict]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action._choices_actions, action.choices


@pytest.mark.parametrize("name", __import__("rotorbayes.cli").cli.COMMANDS)
def test_each_command_is_a_function_with_the_options_as_keywords(name):
    """What the command line passes is what the function takes, with the same defaults
    (so a Python user and the study get what `rotorbayes NAME` would do)."""
    from rotorbayes import cli
    from rotorbayes.commands.common import Outcome

    module = cli.command_module(name)
    assert isinstance(module.HELP, str) and module.HELP
    function = getattr(module, name)
    assert function.__doc__, f"rotorbayes.commands.{name}.{name} needs a docstring"
    assert inspect.signature(function).return_annotation in (Outcome, "Outcome")
    params = inspect.signature(function).parameters
    actions = [a for a in _subparsers(cli.build_parser())[1][name]._actions if a.dest != "help"]
    assert {a.dest for a in actions} == set(params), (
        f"{name}: options {sorted(a.dest for a in actions)} vs keywords {sorted(params)}"
    )
    for a in actions:
        p = params[a.dest]
        required = a.required if a.option_strings else a.nargs in (None, "+")
        if required:
            assert p.default is inspect.Parameter.empty, f"{name} {a.dest} is required"
        elif a.option_strings:
            assert p.default == a.default, (
                f"{name} {a.option_strings[0]}: default {a.default!r} on the command line, "
                f"{p.default!r} in Python"
            )


# --------------------------------------------------------------- typed command options
#: The commands whose work reads one options object, and its class's name.
TYPED_COMMANDS = {
    "fit": "FitOptions",
    "multistart": "MultistartOptions",
    "sample": "SampleOptions",
    "identify": "IdentifyOptions",
}


def _dests(add_group, *args) -> dict[str, argparse.Action]:
    """The options a shared option group adds to a bare parser, by destination."""
    p = argparse.ArgumentParser()
    add_group(p, *args)
    return {a.dest: a for a in p._actions if a.dest != "help"}


@pytest.mark.parametrize("name", sorted(TYPED_COMMANDS))
def test_each_typed_command_option_is_a_field_of_its_options_class(name):
    """Every command-line option of the command sets one field of its options class and
    every field is set by one option, with the same default (required where required)."""
    from rotorbayes import cli
    from rotorbayes.commands import config

    cls = getattr(config, TYPED_COMMANDS[name])
    fields = config.keyword_fields(cls)
    defaults = config.keyword_defaults(cls)
    actions = [a for a in _subparsers(cli.build_parser())[1][name]._actions if a.dest != "help"]
    assert {a.dest for a in actions} == set(fields), (
        f"{name}: options without a field {sorted({a.dest for a in actions} - set(fields))}, "
        f"fields without an option {sorted(set(fields) - {a.dest for a in actions})}"
    )
    for a in actions:
        required = a.required if a.option_strings else a.nargs in (None, "+")
        if required:
            assert a.dest not in defaults, f"{name} {a.dest} is required on the command line"
        else:
            assert a.dest in defaults, f"{name} {a.dest}: optional, but the field is required"
            assert defaults[a.dest] == a.default, (
                f"{name} {a.dest}: default {a.default!r} on the command line, "
                f"{defaults[a.dest]!r} in {cls.__name__}"
            )
    # The Python function's keywords are the same fields (with the defaults tested above).
    function = getattr(cli.command_module(name), name)
    assert set(inspect.signature(function).parameters) == set(fields)


def test_each_shared_option_group_is_one_options_class():
    """The option groups several commands share map onto the shared options classes and
    back: read options, the problem and solver of fit/multistart, the executor, the way a
    fit folder is read again."""
    from rotorbayes.commands import config, options

    def names(cls):
        return set(config.keyword_fields(cls))

    assert set(_dests(options.add_read_options)) == names(config.ReadOptions)
    assert set(_dests(options.add_parallel_options, "tasks")) == names(config.ExecutorOptions)
    folder = {**_dests(options.add_trust_option), **_dests(options.add_changed_data_option)}
    assert set(folder) == names(config.FitFolderOptions)
    fit_group = _dests(options.add_fit_options)
    assert set(fit_group) == (
        names(config.ProblemOptions) | names(config.SolverOptions) | {"out", "force"}
    )
    for cls in (config.ProblemOptions, config.SolverOptions, config.ReadOptions):
        for k, v in config.keyword_defaults(cls).items():
            assert fit_group[k].default == v, f"--{k}: {fit_group[k].default!r} vs {v!r}"


@pytest.mark.parametrize("name", sorted(TYPED_COMMANDS))
def test_each_typed_command_hands_every_keyword_to_its_field(name, monkeypatch):
    """The function builds its options object with each keyword in the field of that name
    (a value given to a command reaches its work unchanged)."""
    from rotorbayes import cli
    from rotorbayes.commands import config

    module = cli.command_module(name)
    cls = getattr(config, TYPED_COMMANDS[name])
    # A distinct value per keyword; the read options must be valid ones (checked at once).
    given = {k: f"value of {k}" for k in config.keyword_fields(cls)}
    valid = {
        "columns": "t=Time,u=Volt",
        "time_unit": "ms",
        "angle_unit": "counts",
        "counts_per_rev": "theta_u=1000,theta_l=2000",
        "data": ("data1.csv", "data2.csv"),
        "validate": ("val1.csv", "val2.csv"),
    }
    given.update({k: v for k, v in valid.items() if k in given})
    seen = []
    monkeypatch.setattr(module, "execute", seen.append)
    getattr(module, name)(**given)
    assert len(seen) == 1 and isinstance(seen[0], cls)
    assert config.keywords(seen[0]) == given
    assert config.keywords(config.from_keywords(cls, **given)) == given


def test_no_command_reads_its_options_from_a_namespace_of_its_locals():
    """``SimpleNamespace(**locals())`` (or any call given ``**locals()``) hides which
    options a step reads; commands pass their typed options instead."""
    bad = []
    for path in MODULES.values():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and any(
                k.arg is None
                and isinstance(k.value, ast.Call)
                and isinstance(k.value.func, ast.Name)
                and k.value.func.id == "locals"
                for k in node.keywords
            ):
                bad.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not bad, "calls given **locals():\n" + "\n".join(bad)


# ----------------------------------------------------------------------------- layers
#: The layers, bottom first.  A module imports (at the top or inside a function) only from
#: its own layer or the layers below: the kernel knows nothing of the model, the model
#: nothing of inference, and so on up to the command line.  ``util`` holds small helpers
#: any layer may use; ``io`` reads and writes files (measurements, rig files, TOML/JSON,
#: output folders); ``commands`` holds each command and the study that runs them.
LAYERS = (
    "kernel",
    "util",
    "io",
    "model",
    "inference",
    "figures",
    "diagnosis",
    "design",
    "report",
    "commands",
    "cli",
    "rotorbayes",
)


def layer_of(module: str) -> str:
    """The layer of a module: the subpackage (or top-level module) it is in."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def layer_violations() -> list[str]:
    rank = {name: i for i, name in enumerate(LAYERS)}
    bad = []
    for importer, target, name, level, line in _imports():
        a, b = layer_of(importer), layer_of(target)
        assert a in rank and b in rank, f"{importer} or {target}: a layer not in LAYERS"
        if rank[b] > rank[a]:
            what = f"{target}.{name}" if name else target
            bad.append(
                f"{MODULES[importer].relative_to(SRC)}:{line} ({level} level) imports "
                f"{what}: layer {b!r} is above {a!r}"
            )
    return bad


def test_every_module_is_in_a_layer():
    assert {layer_of(m) for m in MODULES} <= set(LAYERS)


def test_layers_only_point_down():
    bad = layer_violations()
    assert not bad, "imports that point up a layer:\n" + "\n".join(bad)


def test_the_layer_check_can_fail():
    rank = {name: i for i, name in enumerate(LAYERS)}
    assert rank[layer_of("rotorbayes.kernel.solver")] < rank[layer_of("rotorbayes.model.friction")]
    assert layer_of("rotorbayes.cli") == "cli" and layer_of("rotorbayes") == "rotorbayes"
