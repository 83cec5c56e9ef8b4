"""Typed configuration from plain mappings: the key and type checks every
scenario field goes through, for a config dataclass on its own (a plug-in's
options, a built-in's section), with errors naming the field."""

import dataclasses as dc
import re
import typing

import yaml
from pydrake.common.yaml import yaml_load_typed

from drake_contact.errors import ScenarioError, did_you_mean

#: YAML 1.2 floats (``6.2e4``, ``1e-3``), which YAML 1.1 reads as strings.
YAML12_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X)


def check_schema(schema, data, prefix):
    """Checks a plain mapping against the dataclass ``schema``: every key
    known, every value of its field's type (a YAML 1.1 float string becomes
    a float in ``data``); raises ScenarioError naming ``prefix + key``."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{prefix.rstrip('.') or 'scenario'} must be a mapping of keys, "
                            f"got {data!r}")
    hints = typing.get_type_hints(schema)
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key not in hints:
            fields = [f.name for f in dc.fields(schema)]
            raise ScenarioError(f"{name} is not a scenario key{did_you_mean(key, fields)}: "
                                f"known keys here are {', '.join(fields)}")
        data[key] = _check_type(hints[key], value, name)


def config_from_options(schema, options: dict, prefix: str):
    """``schema`` (a dataclass) from a plain mapping: every key known and of
    its field's type (ScenarioError naming ``prefix.key`` otherwise), then
    validated with ``prefix`` if it has ``validate``. Fields left out keep
    their defaults."""
    data = dict(options)
    check_schema(schema, data, prefix=f"{prefix}.")
    try:
        config = yaml_load_typed(schema=schema, data=yaml.safe_dump(data))
    except (RuntimeError, ValueError, TypeError) as e:
        raise ScenarioError(f"{prefix}: {str(e).splitlines()[0]}") from None
    if hasattr(config, "validate"):
        config.validate(prefix)
    return config


def _check_type(hint, value, name):
    """Returns ``value`` (a YAML 1.1 float string as a float) once it is
    of the field's type; raises ScenarioError naming the field otherwise."""
    if dc.is_dataclass(hint):
        check_schema(hint, value, prefix=f"{name}.")
        return value
    origin = typing.get_origin(hint)
    if origin is list:
        (item_hint,) = typing.get_args(hint)
        if not isinstance(value, list):
            raise ScenarioError(f"{name} = {value!r} must be a list")
        return [_check_type(item_hint, item, f"{name}[{i}]") for i, item in enumerate(value)]
    if hint is float and isinstance(value, str) and YAML12_FLOAT.match(value):
        return float(value.replace("_", ""))
    ok = {
        float: isinstance(value, (int, float)) and not isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        bool: isinstance(value, bool),
        str: isinstance(value, str),
    }.get(hint, True)
    if not ok:
        kind = {float: "a number", int: "a whole number", bool: "true or false",
                str: "a string"}[hint]
        raise ScenarioError(f"{name} = {value!r} must be {kind}")
    return value
