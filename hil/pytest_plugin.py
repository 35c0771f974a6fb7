"""pytest plugin: nightly mocked-hardware tests against your own scene in a few lines.

Installed automatically (entry point ``pytest11``). Example ``test_my_bench.py``::

    def test_my_bench_is_safe(hil_run):
        run = hil_run("scenes/my_bench.yaml", seed=1)      # a path or a built-in scene name
        assert run.completed                               # no safe stop, no error
        energy = run.results("energy_injection")
        assert not energy["went_negative"]                 # E_s(t) >= -noise bound all along

``hil_run(scene, seed=None, experiments=None, max_ticks=None)`` runs the scene on its simulated
bench in lockstep mode into a temporary folder and returns a :class:`HilRun`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest


@dataclass
class HilRun:
    """Outcome of :func:`hil_run`: one :class:`hil.run.runner.ExperimentOutcome` per experiment."""

    scene: Any
    outcomes: list[Any]
    out_dir: Path

    @property
    def completed(self) -> bool:
        return bool(self.outcomes) and all(o.completed for o in self.outcomes)

    def results(self, experiment_type: str) -> dict[str, Any]:
        """Results of the first experiment of that type (e.g. ``"energy_injection"``)."""
        for o in self.outcomes:
            if o.name.split("_", 1)[1] == experiment_type:
                return o.results
        raise KeyError(f"no {experiment_type!r} experiment ran; ran: {[o.name for o in self.outcomes]}")


@pytest.fixture
def hil_run(tmp_path: Path) -> Callable[..., HilRun]:
    """Run a scene on its mocked bench (lockstep) and return a :class:`HilRun`."""

    def run(scene: str | Path, seed: int | None = None, experiments: list[int] | None = None,
            max_ticks: int | None = None) -> HilRun:
        # lazy: pytest loads this plugin in every session of an environment with hil installed
        from hil.run.runner import Runner
        from hil.scene.spec import load_scene

        sc = load_scene(scene)
        if seed is not None:
            sc.seed = seed
        out = tmp_path / f"run-{sc.name}"
        outcomes = Runner(sc, out, realtime=False, max_ticks=max_ticks).run(experiments)
        return HilRun(sc, outcomes, out)

    return run
