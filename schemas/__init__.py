"""JSON Schemas of the file formats avatarkit defines, and one way to validate against them.

The `*.schema.json` files here install as package data of `avatarkit.schemas`. (The loader lives
in this package rather than in a module `avatarkit/schemas.py`: a module of that name would
shadow this package and its files.)
"""
from __future__ import annotations

import functools
import importlib.resources
import json
import os

from avatarkit.errors import FormatError, InputError

#: longest message fragment quoted from a failing instance (they can hold whole arrays)
_MAX_MESSAGE = 160


@functools.lru_cache(maxsize=None)
def _schema_text(name: str) -> str:
    filename = name if name.endswith(".json") else f"{name}.schema.json"
    resource = importlib.resources.files("avatarkit.schemas") / filename
    if not resource.is_file():
        raise InputError(f"no JSON schema named {name!r}")
    return resource.read_text(encoding="utf-8")


def load_schema(name: str) -> dict:
    """The schema `name` ("motion" or "motion.schema.json") as a fresh dict."""
    return json.loads(_schema_text(name))


@functools.lru_cache(maxsize=None)
def _validator(name: str):
    import jsonschema

    schema = load_schema(name)
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def validate(instance, name: str, path: str | os.PathLike | None = None) -> None:
    """Raise FormatError (naming `path` and the JSON path of the problem) unless `instance`
    satisfies schema `name`."""
    import jsonschema

    error = jsonschema.exceptions.best_match(_validator(name).iter_errors(instance))
    if error is None:
        return
    message = error.message
    if len(message) > _MAX_MESSAGE:
        message = message[:_MAX_MESSAGE] + "..."
    raise FormatError(f"does not match the {name} schema at {error.json_path}: {message}", path)
