"""JSON Schema export, so a client in another language can be written from the contract."""

from __future__ import annotations

import json
from pathlib import Path

from .codec import REGISTRY


def json_schemas() -> dict[str, dict]:
    """Schema name (e.g. ``EsdfGrid``) → its JSON Schema (draft 2020-12)."""
    out = {}
    for schema, cls in REGISTRY.items():
        name = schema.split("/")[0]
        js = cls.model_json_schema(mode="validation")
        js["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        js["$id"] = f"riskfield:{schema}"
        js["x-encoding"] = "application/msgpack; arrays as {dtype, shape, data(bin)}"
        out[name] = js
    return out


def export(outdir: str | Path) -> list[Path]:
    """Write ``<Name>.schema.json`` per message into ``outdir``; return the paths."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, js in json_schemas().items():
        p = outdir / f"{name}.schema.json"
        p.write_text(json.dumps(js, indent=2, sort_keys=False) + "\n")
        paths.append(p)
    return paths
