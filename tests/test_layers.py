"""The layer rule (ARCHITECTURE.md), read from the package's imports with ``ast``.

From the bottom up: ``_util``; ``physics`` and ``stats`` (independent of each other);
``trials``; ``inference``; ``comparison``; ``diagnosis``; ``report``; ``jobs``; ``cli``.
A module may import its own layer and those below, never one above, and the modules
import no cycle. ``bayesbeam/__init__`` (the lazy public face) may name every layer.
"""

import ast
import textwrap
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "bayesbeam"

#: layer -> rank; equal ranks may not import each other unless they are the same layer.
RANK = {
    "_util": 0,
    "physics": 1,
    "stats": 1,
    "trials": 2,
    "inference": 3,
    "comparison": 4,
    "diagnosis": 5,
    "report": 6,
    "jobs": 7,
    "cli": 8,
    "__main__": 9,
}


def module_name(path: Path, package: Path) -> str:
    parts = path.relative_to(package.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, package: Path) -> set[str]:
    """Absolute names of the bayesbeam modules (or names) a file imports, anywhere in it."""
    name = module_name(path, package)
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == package.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] != package.name:
                continue
            out.add(mod)
            # ``from bayesbeam.x import y`` may import the submodule bayesbeam.x.y
            out.update(f"{mod}.{a.name}" for a in node.names)
    # lazy_exports tables name modules as strings: count them as imports too
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
            getattr(t, "id", None) == "_EXPORTS" for t in node.targets
        ):
            for v in ast.literal_eval(node.value).values():
                out.add(v if not v.startswith(".") else name + v)
    return out


def modules(package: Path) -> dict[str, Path]:
    return {module_name(p, package): p for p in sorted(package.rglob("*.py"))}


def layer_of(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else None


def violations(package: Path) -> list[str]:
    """Every import against the rule, and every import cycle, as readable lines."""
    mods = modules(package)
    graph: dict[str, set[str]] = {}
    bad = []
    for mod, path in mods.items():
        src = layer_of(mod)
        if src not in RANK and mod != package.name:
            bad.append(f"{mod}: not in a layer (known: {', '.join(RANK)})")
            continue
        deps = {d for d in imports_of(path, package) if d in mods and d != mod}
        graph[mod] = deps
        if mod == package.name:
            continue
        for dep in deps:
            dst = layer_of(dep)
            if dst is None:
                bad.append(f"{mod} imports the top-level package {dep} (import from the module)")
            elif dst != src and RANK[dst] >= RANK[src]:
                bad.append(f"{mod} ({src}) imports {dep} ({dst}): against the layer rule")
    # cycles among modules (subpackage __init__s only re-export lazily: left out)
    real = {m: {d for d in deps if not mods[d].name == "__init__.py"}
            for m, deps in graph.items() if mods[m].name != "__init__.py"}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(real.get(m, ())):
            if state.get(d) == 1:
                bad.append("import cycle: " + " -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(real):
        if m not in state:
            visit(m)
    return bad


def test_package_follows_the_layer_rule():
    assert violations(PACKAGE) == []


def test_no_module_directly_under_the_package_but_init_main_util():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "_util.py"]


def _fake_package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "bayesbeam"
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))
    return root


@pytest.mark.parametrize(
    ("files", "expected"),
    [
        # an upward import: physics may not use inference
        ({"physics/forward.py": "from bayesbeam.inference.fit import fit\n",
          "inference/fit.py": "def fit(): ...\n"}, "against the layer rule"),
        # a sideways import between the two bottom layers
        ({"physics/forward.py": "from bayesbeam.stats import likelihood\n",
          "stats/likelihood.py": ""}, "against the layer rule"),
        # an upward import hidden in a function body, relative form
        ({"trials/trial.py": "def f():\n    from ..report.plots import plot_fit\n",
          "report/plots.py": ""}, "against the layer rule"),
        # a cycle inside one layer
        ({"trials/trial.py": "import bayesbeam.trials.io\n",
          "trials/io.py": "from bayesbeam.trials.trial import Trial\n"}, "import cycle"),
        # a module outside every layer
        ({"helpers.py": "x = 1\n"}, "not in a layer"),
    ],
)
def test_rule_fails_on_bad_imports(tmp_path, files, expected):
    root = _fake_package(tmp_path, files)
    found = violations(root)
    assert any(expected in line for line in found), found


def test_rule_accepts_downward_imports(tmp_path):
    root = _fake_package(tmp_path, {
        "physics/beam.py": "from bayesbeam._util import json_default\n",
        "_util.py": "",
        "trials/trial.py": "from bayesbeam.physics.beam import Beam\n",
        "cli/main.py": "from bayesbeam.trials import trial\nfrom bayesbeam.stats import x\n",
        "stats/x.py": "",
    })
    assert violations(root) == []
