"""Every fingerprint of ``tests/behaviour.py`` equals the committed one: refactors leave what
the package computes unchanged. A change of physics regenerates the fixture on purpose
(``python -m tests.behaviour --update``) in the same commit."""

from __future__ import annotations

import json

import pytest

from tests.behaviour import CASES, FIXTURE, fingerprint, record, same_behaviour


@pytest.mark.parametrize("name", sorted(CASES))
def test_behaviour_is_unchanged(name):
    committed = json.loads(FIXTURE.read_text())
    same, why = same_behaviour(CASES[name](), committed[name])
    assert same, (
        f"'{name}' computes something else than the committed fingerprint ({why}). A refactor "
        "must not change it; a change of physics regenerates tests/fixtures/behaviour.json "
        "(python -m tests.behaviour --update) and says so in its commit.")


def test_a_machines_last_bits_pass_and_a_change_in_the_sixth_digit_does_not():
    import numpy as np

    x = np.linspace(600.0, 640.0, 1000)
    committed = record({"x": x, "y": np.arange(3.0)})
    drift = x.copy()
    drift[::7] = np.nextafter(drift[::7].astype(np.float32), np.float32(1e9)).astype(float)
    assert fingerprint({"x": drift, "y": np.arange(3.0)}) != committed["sha256"]
    assert same_behaviour({"x": drift, "y": np.arange(3.0)}, committed)[0]
    moved = x.copy()
    moved[100:200] *= 1.0 + 1e-5
    same, why = same_behaviour({"x": moved, "y": np.arange(3.0)}, committed)
    assert not same and why == "moved: x"
    assert not same_behaviour({"x": x}, committed)[0]


def test_a_fingerprint_sees_a_change_in_the_seventh_digit():
    import numpy as np

    base = {"x": np.linspace(1.0, 2.0, 1000)}
    moved = {"x": base["x"] * (1.0 + 1e-6)}
    assert fingerprint(base) != fingerprint(moved)
    assert fingerprint(base) == fingerprint({"x": base["x"] * (1.0 + 1e-12)})
