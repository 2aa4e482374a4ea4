"""Typed settings from mappings: the one place that turns a config mapping into a settings object.

Defaults live in frozen dataclasses (`GFCSConfig`, `PPOConfig`, `EnvConfig`, `VAEConfig`, ...);
YAML files under configs/ are named presets over them, read only by the CLI, the experiments, the
viewer and notebooks (`fabrax.config`). `from_mapping(cls, mapping, where)` builds a dataclass
from such a mapping: an unknown key or a value of the wrong type raises one `ValueError` line that
names it (`where.key`), before anything is traced. Lists become tuples, so the result hashes and
can be a static argument of `jax.jit`.
"""

from __future__ import annotations

import dataclasses
import functools
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

T = TypeVar("T")


def check_keys(mapping: Mapping, known: Iterable[str], where: str) -> None:
    """Raise `ValueError("unknown <where> keys [...] (known: ...)")` when `mapping` holds a key not in `known`."""
    known = list(known)
    unknown = sorted(map(str, set(mapping) - set(known)))
    if unknown:
        raise ValueError(f"unknown {where} keys {unknown} (known: {', '.join(sorted(known))})")


@functools.cache
def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def from_mapping(cls: type[T], mapping: Mapping | T | None, where: str, base: T | None = None) -> T:
    """A `cls` (a dataclass) with `mapping`'s values over its defaults (or over `base`, an instance),
    each converted to its field's type: nested dataclasses from nested mappings (over the field's
    own default), tuples from lists, floats from ints. An instance of `cls` passes through; None
    gives the defaults."""
    if isinstance(mapping, cls):
        return mapping
    mapping = {} if mapping is None else mapping
    if not isinstance(mapping, Mapping):
        raise ValueError(f"{where} must be a mapping of {cls.__name__} fields, got {type(mapping).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    check_keys(mapping, fields, where)
    hints = _hints(cls)
    out = {}
    for k, v in mapping.items():
        default = getattr(base, k) if base is not None else fields[k].default
        if dataclasses.is_dataclass(default) and not isinstance(default, type) and isinstance(v, Mapping):
            out[k] = from_mapping(type(default), v, f"{where}.{k}", base=default)
        else:
            out[k] = _convert(hints[k], v, f"{where}.{k}")
    return cls(**out) if base is None else dataclasses.replace(base, **out)


def _convert(tp, value, name: str):
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any or tp is object:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _convert(option, value, name)
            except ValueError as e:
                errors.append(str(e))
        raise ValueError(errors[0] if len(errors) == 1 else f"{name} must be one of {[_name(o) for o in options]}, got {value!r}")
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, name)
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if tp is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return value
    if tp is float:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(f"{name} must be a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
        return value
    if origin is tuple or tp is tuple:
        if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
            raise ValueError(f"{name} must be a list, got {value!r}")
        items = list(value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{name}[{i}]") for i, v in enumerate(items))
        if args and len(items) != len(args):
            raise ValueError(f"{name} must have {len(args)} entries, got {len(items)}")
        return tuple(_convert(a, v, f"{name}[{i}]") for i, (a, v) in enumerate(zip(args, items))) if args else tuple(items)
    if origin is typing.Literal:
        if value not in args:
            raise ValueError(f"{name} must be one of {list(args)}, got {value!r}")
        return value
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise ValueError(f"{name} must be a mapping, got {value!r}")
        return dict(value)
    return value


def _name(tp) -> str:
    return getattr(tp, "__name__", str(tp))
