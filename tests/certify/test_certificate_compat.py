"""Certificates written by an earlier version keep their digest: fields added to the schema after
1.1 are marked ``since`` and left out of the canonical content while they hold their default.

The fixtures in tests/data/certificates_v1_1/ were written by ``hil certify`` at commit 3d0cf5e
(schema 1.1): the default SDEA bench (GO, with identification and design) and bilateral_2dof_B
(NO-GO, with a witness and energy evidence), with that version's JSON schema.
"""

from __future__ import annotations

import gzip
import json
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

from hil.certify.certificate import Certificate, Series, content_digest
from hil.report.render import load_certificate

DATA = Path(__file__).resolve().parents[1] / "data" / "certificates_v1_1"


def _fixtures() -> list[Path]:
    return sorted(p for p in DATA.glob("*.json.gz") if p.name != "certificate.schema.json.gz")


@pytest.mark.parametrize("path", _fixtures(), ids=lambda p: p.name)
def test_v1_1_certificate_keeps_its_digest(path: Path, tmp_path: Path) -> None:
    raw = gzip.decompress(path.read_bytes()).decode("utf-8")
    stored = json.loads(raw)["integrity"]["digest"]
    f = tmp_path / "certificate.json"
    f.write_text(raw, encoding="utf-8")
    cert = load_certificate(f)
    assert cert.schema_version == "1.1"
    assert content_digest(cert) == stored
    # and any edit of a value still breaks it
    edited = json.loads(raw)
    edited["reasons"] = [*edited["reasons"], "edited"]
    f.write_text(json.dumps(edited), encoding="utf-8")
    assert content_digest(load_certificate(f)) != stored


def _models(m: type[BaseModel], seen: dict[str, type[BaseModel]]) -> dict[str, type[BaseModel]]:
    if m.__name__ in seen:
        return seen
    seen[m.__name__] = m
    for f in m.model_fields.values():
        stack = [f.annotation]
        while stack:
            a = stack.pop()
            if isinstance(a, type) and issubclass(a, BaseModel):
                _models(a, seen)
            stack.extend(typing.get_args(a))
    return seen


def test_every_field_added_after_1_1_is_marked_since() -> None:
    """The guard: a field not in the 1.1 schema must carry ``since`` (else old digests break)."""
    old = json.loads(gzip.decompress((DATA / "certificate.schema.json.gz").read_bytes()))
    missing = []
    for name, m in _models(Certificate, {}).items():
        props = old["properties"] if name == "Certificate" else old["$defs"].get(name, {}).get("properties")
        if props is None:  # a model new in 1.2: only reachable through a field that is marked itself
            continue
        for fname, f in m.model_fields.items():
            key = f.alias or fname
            if props is not None and key in props:
                continue
            extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
            if "since" not in extra:
                missing.append(f"{name}.{key}")
    assert not missing, f"fields added after schema 1.1 without json_schema_extra=SINCE_1_2: {missing}"


def test_a_new_field_with_a_value_is_covered_by_the_digest() -> None:
    """Left out only at its default: set, it is part of the content like any other field."""
    base = Series(title="t", x=[1.0, 2.0], x_label="x [1]", y_label="y [1]", lines={"a": [0.0, 1.0]})
    marked = base.model_copy(update={"shade_negative": True})
    from hil.certify.certificate import drop_new_defaults

    d0 = json.loads(base.model_dump_json())
    d1 = json.loads(marked.model_dump_json())
    drop_new_defaults(base, d0)
    drop_new_defaults(marked, d1)
    assert "shade_negative" not in d0 and d1["shade_negative"] is True
