"""Bind, compile and cache generated step loops.

A generated module (:mod:`.generate`, :mod:`.lanes`) calls its effect functions through module
globals; the loader sets them (compiled, or plain Python for the reference kernel) before the
module's code runs, so generated code imports nothing of the package. The source is written to
``$EBUS_CACHE_DIR`` (default ``~/.cache/ebus_env/kernels``) under a name that hashes the source,
the effects' source files and the library versions, and compiled with numba's on-disk cache: a
second process with the same model loads machine code instead of compiling. The same source
executed as plain Python (:func:`python_kernel`) is the reference the tests compare the
compiled loop with.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from types import ModuleType
from typing import Any

import numba
import numpy as np

from ebus_env.model import template
from ebus_env.model.generate import Composition, Layout, function_global
from ebus_env.model.lanes import lane_source

_LOCK = threading.Lock()


def bindings(comp: Composition, calls: Iterable[tuple[str, str]], python: bool
             ) -> dict[str, Callable]:
    """Globals of a generated module: the functions of ``calls`` ((effect, call site) pairs),
    compiled or plain (``python``), and the template's helpers."""
    effects = {eff.name: eff for eff in comp.effects}
    names: dict[str, Callable] = {}
    for effect_name, site in calls:
        eff = effects[effect_name]
        names[function_global(effect_name, site)] = (eff.calls[site].function if python
                                                     else eff.jitted(site))
    names["_move"] = template.move.py_func if python else template.move
    return names


def _library_fingerprint() -> str:
    """Hash of the library code a kernel depends on (effects, tables, template)."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(list((root / "effects").glob("*.py")) + list((root / "model").glob("*.py"))):
        h.update(path.read_bytes())
    h.update(f"{numba.__version__} {np.__version__} {sys.version}".encode())
    return h.hexdigest()


_FINGERPRINT: str | None = None


def kernel_key(comp: Composition, source: str) -> str:
    """Cache key: the source, every effect's source file and the library fingerprint."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        _FINGERPRINT = _library_fingerprint()
    h = hashlib.sha256(source.encode())
    h.update(_FINGERPRINT.encode())
    for eff in comp.effects:
        for path in sorted(eff.source_files):
            h.update(Path(path).read_bytes())
        for call in eff.calls.values():
            h.update(inspect.getsource(call.function).encode())
    return h.hexdigest()[:20]


def cache_dir() -> Path:
    """Directory of generated kernels (``$EBUS_CACHE_DIR`` or ``~/.cache/ebus_env/kernels``)."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "ebus_env"
    path = Path(os.environ.get("EBUS_CACHE_DIR", default)) / "kernels"
    path.mkdir(parents=True, exist_ok=True)
    return path


def compile_kernel(comp: Composition, layout: Layout) -> ModuleType:
    """Import the generated module with its loops jitted (``run_compiled``,
    ``run_record_compiled``, ``run_sample_compiled``); each compiles, or loads from the disk
    cache, on first call."""
    return _compile(comp, layout.source, ("run", "run_record", "run_sample"), layout.calls)


def compile_lanes(comp: Composition, layout: Layout, varying: Iterable[int]) -> ModuleType:
    """The lane loops for parameters that differ in the columns ``varying`` (:func:`lane_source`),
    jitted as ``run_lanes_compiled`` and ``run_sample_lanes_compiled``."""
    return _compile(comp, lane_source(layout, varying), ("run_lanes", "run_sample_lanes"),
                    layout.calls)


def lanes_compiled(comp: Composition, layout: Layout, varying: Iterable[int]) -> bool:
    """Whether the lane loops for ``varying`` are compiled already: imported in this process,
    or ``run_sample_lanes`` in numba's disk cache (its index file) from an earlier one."""
    name = f"ebus_kernel_{kernel_key(comp, lane_source(layout, varying))}"
    return name in sys.modules or any(
        (cache_dir() / "__pycache__").glob(f"{name}.run_sample_lanes-*.nbi"))


def _compile(comp: Composition, source: str, names: Iterable[str],
             calls: Iterable[tuple[str, str]]) -> ModuleType:
    key = kernel_key(comp, source)
    with _LOCK:
        module_name = f"ebus_kernel_{key}"
        if module_name in sys.modules:
            return sys.modules[module_name]
        path = cache_dir() / f"{module_name}.py"
        if not path.exists() or path.read_text() != source:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(source)
            os.replace(tmp, path)
        spec = importlib.util.spec_from_file_location(module_name, path)
        if spec is None or spec.loader is None:
            raise ImportError(f"Cannot load the generated kernel {path}.")
        module = importlib.util.module_from_spec(spec)
        vars(module).update(bindings(comp, calls, python=False))
        spec.loader.exec_module(module)
        for name in names:
            jitted = numba.njit(cache=True, nogil=True, error_model="numpy")(getattr(module, name))
            setattr(module, name + "_compiled", jitted)
        sys.modules[module_name] = module
        return module


def python_kernel(comp: Composition, layout: Layout) -> dict[str, Callable]:
    """The same loops as plain Python (effects uncompiled): slow, for tests and debugging."""
    namespace: dict[str, Any] = {**bindings(comp, layout.calls, python=True),
                                 "__name__": "ebus_kernel_python"}
    exec(compile(layout.source, "<ebus kernel (python)>", "exec"), namespace)
    return {name: namespace[name] for name in ("run", "run_record", "run_sample")}
