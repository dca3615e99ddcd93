"""Hydra structured configs from the library's frozen parameter dataclasses.

Library parameters (e.g. :class:`~jaxloco.planner.PSPParams`) are frozen dataclasses: they
are hashable, so they can be static arguments under ``jit``, and they validate themselves.
Hydra treats a frozen dataclass node as read-only, which would forbid ``key=value``
overrides. :func:`config_schema` derives a mutable twin with the same fields, types and
defaults (so no number is written twice), and :func:`to_params` turns a composed config node
back into the frozen class, running its validation (a bad override fails there, with an
error that names the field).
"""

from __future__ import annotations

import dataclasses
import functools
import typing

from omegaconf import DictConfig, OmegaConf


@functools.cache
def config_schema(params_cls: type, defaults=None) -> type:
    """A mutable dataclass with ``params_cls``'s fields and types.

    Defaults are the class's own, or the field values of ``defaults`` (an instance, e.g. a
    preset) when given.
    """
    if not dataclasses.is_dataclass(params_cls):
        raise TypeError(f"{params_cls!r} is not a dataclass")
    hints = typing.get_type_hints(params_cls)
    fields = []
    for f in dataclasses.fields(params_cls):
        hint = hints[f.name]
        default = f.default if defaults is None else getattr(defaults, f.name)
        if (
            typing.get_origin(hint) is typing.Union
            and len(set(typing.get_args(hint)) - {type(None)}) > 1
        ):
            # OmegaConf's unions refuse an int for a float (``=300``): any value here, and
            # the class's own validation in to_params.
            hint = typing.Any
        if typing.get_origin(hint) is tuple:
            # OmegaConf has no tuples: a list in the config, a tuple again in to_params.
            args = set(typing.get_args(hint)) - {Ellipsis}
            inner = args.pop() if len(args) == 1 else typing.Any
            # Nor nested generics (e.g. tuples of pairs): Any elements there.
            hint = list[typing.Any] if typing.get_origin(inner) is not None else list[inner]
            if default is not dataclasses.MISSING:
                default_list = list(default)
                spec = dataclasses.field(default_factory=lambda d=default_list: list(d))
                fields.append((f.name, hint, spec))
                continue
        if default is not dataclasses.MISSING:
            spec = dataclasses.field(default=default)
        elif f.default_factory is not dataclasses.MISSING:
            spec = dataclasses.field(default_factory=f.default_factory)
        else:
            spec = dataclasses.field()
        fields.append((f.name, hint, spec))
    schema = dataclasses.make_dataclass(f"{params_cls.__name__}Config", fields)
    schema.__doc__ = f"Hydra schema for :class:`{params_cls.__module__}.{params_cls.__name__}`."
    schema.__module__ = __name__
    return schema


def to_params(params_cls: type, node):
    """Build the frozen ``params_cls`` from a config node (DictConfig, dict or schema object)."""
    if isinstance(node, DictConfig):
        values = OmegaConf.to_container(node, resolve=True)
    elif dataclasses.is_dataclass(node):
        values = dataclasses.asdict(node)
    else:
        values = dict(node)
    known = {f.name for f in dataclasses.fields(params_cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{params_cls.__name__} has no field(s) {unknown}; valid: {sorted(known)}")
    hints = typing.get_type_hints(params_cls)
    values = {
        k: tuple(v) if typing.get_origin(hints[k]) is tuple and isinstance(v, list) else v
        for k, v in values.items()
    }
    return params_cls(**values)
