"""The scene field reference (docs/scene-reference.md) is generated from the schema and current:
every field of every mapping the loader accepts, with the unit the loader names in its errors, the
range it enforces and the default it fills in."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

from hil.scene import reference as ref
from hil.scene.spec import Safety, Scene, SensorNoise, load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "scene-reference.md"


def test_the_committed_reference_is_the_generated_one():
    assert DOC.read_text(encoding="utf-8") == ref.reference_markdown(), (
        "docs/scene-reference.md is out of date: python -m hil.scene.reference --write docs/scene-reference.md")


def test_check_mode_fails_on_a_stale_file(tmp_path, capsys):
    stale = tmp_path / "ref.md"
    stale.write_text(ref.reference_markdown().replace("| `safety.max_effort` |", "| `safety.max_force` |"))
    assert ref.main(["--check", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().err
    fresh = tmp_path / "fresh.md"
    assert ref.main(["--write", str(fresh)]) == 0 and ref.main(["--check", str(fresh)]) == 0


def _all_rows() -> dict[str, ref.Row]:
    return {r.path: r for _, _, rs in ref.rows() for r in rs}


def _leaf_names(model: type[BaseModel]) -> set[str]:
    return set(model.model_fields)


def test_every_field_of_every_reachable_model_is_listed():
    """An independent walk of the models the scene's annotations reach: each of their fields has a
    row whose path ends with it."""
    rows = _all_rows()
    ends = {p.rsplit(".", 1)[-1] for p in rows}
    seen: set[type] = set()

    def reach(tp: typing.Any) -> None:
        for a in typing.get_args(tp):
            reach(a)
        if isinstance(tp, type) and issubclass(tp, BaseModel) and tp not in seen:
            seen.add(tp)
            for f in tp.model_fields.values():
                reach(f.annotation)

    reach(Scene)
    assert len(seen) > 20  # devices, simulation, controllers, experiments, certification, ...
    missing = [(m.__name__, n) for m in seen for n in _leaf_names(m) if (m.model_fields[n].alias or n) not in ends]
    assert not missing, missing


@pytest.mark.parametrize("model,path_prefix", [(Safety, "safety"), (SensorNoise, "simulation.sensor_noise")])
def test_units_ranges_and_defaults_follow_the_loader(model, path_prefix):
    rows = _all_rows()
    for name, info in model.model_fields.items():
        r = rows[f"{path_prefix}.{name}"]
        # the default the loader fills in
        d = model().model_dump()[name] if all(f.default is not None or f.default_factory for f in
                                              model.model_fields.values()) else info.default
        if isinstance(d, float):
            assert r.default == ref._num(d), (name, r.default, d)
    # spot values, stated independently of the generator
    assert rows["safety.max_effort"].unit == "N or N.m" and rows["safety.max_effort"].range == "> 0"
    assert rows["safety.watchdog_ms"].unit == "ms" and rows["safety.watchdog_ms"].default == "50"
    assert rows["safety.max_overrun_fraction"].unit == "1" and rows["safety.max_overrun_fraction"].range == "≥ 0, ≤ 1"
    assert rows["simulation.sensor_noise.velocity_std"].unit == "m/s or rad/s"
    assert rows["rate_hz"].unit == "Hz" and rows["rate_hz"].range == "> 0, ≤ 100000"
    assert rows["rate_hz"].default == "1000"
    assert rows["devices"].default == "required" and rows["devices"].range == "at least 1 item"
    assert rows["certification.draws"].range == "≥ 20, ≤ 100000"


def test_a_value_outside_the_stated_range_is_refused_naming_the_field():
    """The ranges are the loader's: a value just outside one is refused, naming the field."""
    from hil.errors import HilError

    d = __import__("yaml").safe_load(load_scene("sdea_bench").source_text)
    d["safety"]["max_effort"] = 0
    with pytest.raises(HilError, match="max_effort"):
        scene_from_dict(d, label="x")


def test_every_number_has_a_unit_or_says_it_is_dimensionless():
    for path, r in _all_rows().items():
        if r.type.startswith("number"):
            assert r.unit and r.unit != "—", path
