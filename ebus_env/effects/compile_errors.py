"""A numba compile failure, told as the user's mistake: which effect, file and line, and what
to do (numba's own message names none of them and often blames the wrong thing)."""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable, Iterable

from ebus_env.effects.base import Call, Effect, registered_effects
from ebus_env.errors import CompositionError

_FIX = ("Fix: effects run compiled, so every function an effect calls needs the @helper "
        "decorator (from ebus_env import helper), and an effect may use only numbers, "
        "math/numpy functions and its parameters (no dicts, strings, lists or Python objects).")


def _where(function: Callable) -> tuple[str, int, list[str]]:
    lines, first = inspect.getsourcelines(function)
    return inspect.getsourcefile(function) or "?", first, lines


def explain(exc: BaseException, effects: Iterable[Effect] = ()) -> CompositionError | None:
    """The effect a numba ``TypingError`` comes from, as a :class:`CompositionError` (None
    when ``exc`` is no compile failure or no effect can be blamed). Where numba names no line
    of an effect (a wrong number or type of return values fails in the generated loop), the
    model's own ``effects`` are called once in Python to find the one that returns what its
    sink or slot does not take."""
    try:
        from numba.core.errors import TypingError
    except ImportError:  # pragma: no cover - numba is a core dependency
        return None
    if not isinstance(exc, TypingError):
        return None
    text = str(exc)
    cause = next((line.strip() for line in text.splitlines()
                  if line.strip() and not line.startswith(("Failed in", "During"))), text)
    located = re.findall(r'File "([^"]+)", line (\d+)', text)
    names = set(re.findall(r"(?:name|global name) '(\w+)'", text))
    for eff in registered_effects().values():
        for site, call in eff.calls.items():
            try:
                file, first, lines = _where(call.function)
            except (OSError, TypeError):
                continue
            hit = next((int(n) for f, n in located if f == file
                        and first <= int(n) < first + len(lines)), None)
            if hit is None and names & set(call.function.__code__.co_names):
                name = sorted(names & set(call.function.__code__.co_names))[0]
                hit = next((first + i for i, line in enumerate(lines)
                            if re.search(rf"\b{name}\b", line) and i > 0), first)
            if hit is not None:
                return CompositionError(f"Effect '{_label(eff, site)}' ({file}, line {hit}) "
                                        f"cannot be compiled by numba: {cause}. {_FIX}")
    for eff in effects:
        for site, call in eff.calls.items():
            wrong = _wrong_returns(call)
            if wrong is not None:
                file, first, _ = _where(call.function)
                role = f"a contribution to {eff.sink}" if eff.sink else f"slot {eff.slot}"
                return CompositionError(
                    f"Effect '{_label(eff, site)}' ({file}, line {first}) returns {wrong}; as "
                    f"{role} it must "
                    f"return {len(call.returns)} number(s): "
                    f"{', '.join(r.replace('__contribution__', 'its contribution') for r in call.returns)}. "
                    "Fix: return exactly these, in this order (a state's next value for each "
                    "state it keeps, named in returns=).")
    return None


def _label(eff: Effect, site: str) -> str:
    """An effect's name, with its call site where it has several."""
    return eff.name if site == "main" else f"{eff.name} ({site})"


def _wrong_returns(call: Call) -> str | None:
    """What ``call`` returns when called in Python with 1.0 for every argument, where that is
    not as many numbers as it declares (None when it is, or when the call fails on such
    arguments: then it is not the return values numba tripped over)."""
    import numbers

    try:
        out = call.function(*[1.0] * len(call.arguments))
    except Exception:  # a table, a division by zero...: not this check's to judge
        return None
    values = out if isinstance(out, tuple) else (out,)
    numeric = all(isinstance(v, numbers.Number) and not isinstance(v, complex) for v in values)
    if numeric and len(values) == len(call.returns):
        return None
    kinds = ", ".join(type(v).__name__ for v in values)
    return f"{len(values)} value(s) ({kinds})"
