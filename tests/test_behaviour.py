"""Every fingerprint of ``tests/behaviour.py`` equals the committed one: refactors leave what
the package computes unchanged. A change of physics regenerates the fixture on purpose
(``python -m tests.behaviour --update``) in the same commit."""

from __future__ import annotations

import json

import pytest

from tests.behaviour import CASES, FIXTURE, fingerprint


@pytest.mark.parametrize("name", sorted(CASES))
def test_behaviour_is_unchanged(name):
    committed = json.loads(FIXTURE.read_text())
    assert fingerprint(CASES[name]()) == committed[name], (
        f"'{name}' computes something else than the committed fingerprint. A refactor must not "
        "change it; a change of physics regenerates tests/fixtures/behaviour.json "
        "(python -m tests.behaviour --update) and says so in its commit.")


def test_a_fingerprint_sees_a_change_in_the_seventh_digit():
    import numpy as np

    base = {"x": np.linspace(1.0, 2.0, 1000)}
    moved = {"x": base["x"] * (1.0 + 1e-6)}
    assert fingerprint(base) != fingerprint(moved)
    assert fingerprint(base) == fingerprint({"x": base["x"] * (1.0 + 1e-12)})
