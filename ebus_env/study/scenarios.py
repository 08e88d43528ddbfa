"""The scenarios of a study: every infrastructure option with every strategy."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

from ebus_env.study.study_file import Infrastructure, Strategy, StudySpec


@dataclass(frozen=True)
class Scenario:
    """One infrastructure option run with one strategy, over all of the study's days."""

    index: int
    infrastructure: Infrastructure
    strategy: Strategy

    @property
    def name(self) -> str:
        return f"{self.infrastructure.name}__{self.strategy.name}"

    def key(self, spec: StudySpec) -> str:
        """A file-safe name that changes when anything the scenario's rows depend on does
        (lines, climate, days, costs, option, strategy): ``--resume`` never reuses rows of
        another study."""
        data = {k: v for k, v in spec.raw.items() if k not in ("infrastructure", "strategies",
                                                              "name")}
        data["scenario"] = [asdict(self.infrastructure), asdict(self.strategy)]
        digest = hashlib.sha1(json.dumps(data, sort_keys=True, default=str).encode())
        return f"{self.index:04d}_{digest.hexdigest()[:10]}"

    def columns(self) -> dict:
        """The scenario's identifying columns of a result row."""
        return {"scenario": self.name, "infrastructure": self.infrastructure.name,
                "strategy": self.strategy.name, **asdict(self.infrastructure)}


def scenarios(spec: StudySpec) -> list[Scenario]:
    """Infrastructure options x strategies, in the file's order."""
    return [Scenario(i * len(spec.strategies) + j, infra, strategy)
            for i, infra in enumerate(spec.infrastructure)
            for j, strategy in enumerate(spec.strategies)]
