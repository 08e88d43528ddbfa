"""The package's layers point down: no module imports from a layer above its own (lazy imports
inside functions included), and ``ebus_env`` never imports the ``agents`` that use it."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

LAYERS = (  # lowest first; a module may import its own layer and those below
    ("ebus_env.errors", "ebus_env.units", "ebus_env.signals", "ebus_env.paths", "ebus_env.inputs",
     "ebus_env.outputs", "ebus_env.html_report", "ebus_env.cli_options"),
    ("ebus_env.effects", "ebus_env.profile", "ebus_env.grade", "ebus_env.resample"),
    ("ebus_env.model",),
    ("ebus_env.config", "ebus_env.bus_choice"),
    ("ebus_env.cycles", "ebus_env.routes", "ebus_env.io", "ebus_env.synthetic",
     "ebus_env.simulate", "ebus_env.blocks", "ebus_env.plotting"),
    ("ebus_env.calibration", "ebus_env.gtfs"),
    ("ebus_env.diagnostics", "ebus_env.envs"),
    ("ebus_env.console", "ebus_env.demo"),
    ("ebus_env.study", "ebus_env.depot"),
    ("ebus_env.twin",),
    ("ebus_env.cli",),
    ("agents",),
)
INNER = {  # layers inside a package, the same way
    "ebus_env.model": (("ebus_env.model.template", "ebus_env.model.threads",
                        "ebus_env.model.results"),
                       ("ebus_env.model.generate",), ("ebus_env.model.lanes",),
                       ("ebus_env.model.kernels",), ("ebus_env.model.model",)),
    "ebus_env.envs": (("ebus_env.envs.climate", "ebus_env.envs.reward", "ebus_env.envs.reference_vehicle",
                       "ebus_env.envs.course", "ebus_env.envs.render", "ebus_env.envs.env_config"),
                      ("ebus_env.envs.batch",), ("ebus_env.envs.charging_site",),
                      ("ebus_env.envs.common",),
                      ("ebus_env.envs.ebus", "ebus_env.envs.vector", "ebus_env.envs.fleet"),
                      ("ebus_env.envs.sb3",)),
}
FACADES = {"ebus_env", "ebus_env.envs", "ebus_env.model"}  # package inits: names, no logic


def level(module: str, layers) -> int | None:
    for i, names in enumerate(layers):
        if any(module == n or module.startswith(n + ".") for n in names):
            return i
    return None


def modules():
    for path in sorted([*(ROOT / "ebus_env").rglob("*.py"), *(ROOT / "agents").rglob("*.py")]):
        parts = path.relative_to(ROOT).with_suffix("").parts
        yield ".".join(parts[:-1] if parts[-1] == "__init__" else parts), path


def imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from ((a.name, node.lineno) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module, node.lineno


def violations() -> list[str]:
    found = []
    for module, path in modules():
        if module in FACADES:
            continue
        mine = level(module, LAYERS)
        if mine is None:
            found.append(f"{module}: in no layer; add it to LAYERS in tests/test_layers.py")
            continue
        found += [f"{module}: in no layer of {package}; add it to INNER"
                  for package, inner in INNER.items()
                  if module.startswith(package + ".") and level(module, inner) is None]
        for target, line in imports(path):
            theirs = level(target, LAYERS)
            if target in FACADES or theirs is None:
                continue  # the package's facade, or a third-party module
            where = f"{path.relative_to(ROOT)}:{line} imports {target}"
            if theirs > mine:
                found.append(f"{where}, a layer above")
            for package, inner in INNER.items():
                if module.startswith(package + ".") and target.startswith(package + "."):
                    a, b = level(module, inner), level(target, inner)
                    if a is not None and b is not None and b > a:
                        found.append(f"{where}, a layer above inside {package}")
    return found


def test_no_module_imports_from_a_layer_above_its_own():
    assert violations() == []


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The check fails where it should: a model module that imports the envs."""
    fake = tmp_path / "ebus_env" / "model" / "up.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("def f():\n    from ebus_env.envs.ebus import EBusEnv\n")
    (tmp_path / "agents").mkdir()
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert violations() == ["ebus_env.model.up: in no layer of ebus_env.model; add it to INNER",
                            "ebus_env/model/up.py:2 imports ebus_env.envs.ebus, a layer above"]


def test_ebus_env_never_imports_agents():
    up = [f"{path.relative_to(ROOT)}:{line}" for path in (ROOT / "ebus_env").rglob("*.py")
          for target, line in imports(path) if target.split(".")[0] == "agents"]
    assert up == []


def test_no_two_modules_share_a_name():
    """A module's name says where it belongs: no two in ebus_env/ and agents/ share one."""
    seen: dict[str, list[str]] = {}
    for module, path in modules():
        if path.name != "__init__.py":
            seen.setdefault(path.stem, []).append(module)
    assert {name: where for name, where in seen.items() if len(where) > 1} == {}


def test_the_study_drives_buses_only_through_the_site_step():
    """The study and the fleet env share one site step (ebus_env.envs.charging_site): the
    study neither shares plugs itself nor reaches into a batch's input rows."""
    import re

    found = [f"{path.relative_to(ROOT)}: {word}" for path in (ROOT / "ebus_env" / "study")
             .rglob("*.py") for word in (r"\bshare_site\b", r"\brows_at\b",
                                         r"(?<!ebus_env)\.inputs\b")
             if re.search(word, path.read_text())]
    assert found == []
