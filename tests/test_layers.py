"""The architecture, checked on the source: the library (plant, sensing,
control, identification, scoring, faults, and the scenario, diagram,
simulation, visualization and interface modules) never imports the
application (drake_contact.app), and no module imports
itself back through others, at module level or inside a function."""

import ast
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "drake_contact"
#: The package's front door re-exports both layers; it is nobody's import.
FACADES = {"drake_contact", "drake_contact.__main__", "drake_contact.gym"}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """drake_contact modules ``path`` imports, anywhere in the file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("drake_contact")}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("drake_contact"):
            found.add(node.module)
    return found


def graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: {m for m in imports(path) if m in modules and m not in FACADES}
            for name, path in modules.items() if name not in FACADES}


def test_the_library_never_imports_the_application():
    offenders = {name: sorted(m for m in deps if m.startswith("drake_contact.app"))
                 for name, deps in graph().items() if not name.startswith("drake_contact.app")}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, offenders
    assert len(graph()) > 25  # the walk found the modules


def test_no_import_cycle():
    deps = graph()
    done, path = set(), []

    def visit(name):
        if name in path:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(name):] + [name]))
        if name in done:
            return
        path.append(name)
        for dep in sorted(deps[name]):
            visit(dep)
        path.pop()
        done.add(name)
    for name in sorted(deps):
        visit(name)


def test_the_walk_would_see_a_cycle_and_a_layer_breach(tmp_path, monkeypatch):
    """The checks can fail: a planted breach is found."""
    fake = tmp_path / "drake_contact"
    (fake / "app").mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    (fake / "app" / "__init__.py").write_text("")
    (fake / "a.py").write_text("from drake_contact.app.b import x\n")
    (fake / "app" / "b.py").write_text("def f():\n    from drake_contact.a import y\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    with pytest.raises(AssertionError, match="'drake_contact.a': \\['drake_contact.app.b'\\]"):
        test_the_library_never_imports_the_application()
    with pytest.raises(AssertionError, match="import cycle: drake_contact.a -> drake_contact.app.b"):
        test_no_import_cycle()


def test_building_simulating_logging_and_scoring_a_run_are_library():
    import drake_contact
    for name in ("MakeContactDiagram", "AddSignalLoggers", "MakeRunDiagram", "simulate",
                 "simulate_scenario", "RunResult", "compute_metrics"):
        module = drake_contact._MODULE_OF[name]
        assert not module.startswith("drake_contact.app"), (name, module)
        assert getattr(drake_contact, name).__module__ == module
