"""Hydra config composition from the `configs/` tree, dataclass views of config nodes, and the checks every value
passes where it is read: types, ranges, choices and output paths, each failure one ConfigError naming the key,
the value and what is allowed."""

from __future__ import annotations

import dataclasses
import os
import tempfile
import types
import typing
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar

from hydra import compose, initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.errors import HydraException
from omegaconf import DictConfig, ListConfig, OmegaConf

from .errors import ConfigError

T = TypeVar("T")

CONFIG_DIR = Path(os.environ.get("COSMOS_LITE_CONFIGS", Path(__file__).resolve().parent.parent / "configs"))
VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov")  # containers write_video fills with H.264


def register(group: str, name: str, node: type) -> None:
    """Register dataclass `node` in Hydra's ConfigStore as the structured config `group/name`: the one place its
    defaults live (YAML files pick it in their defaults list and hold only what differs); keys are type-checked."""
    ConfigStore.instance().store(group=group, name=name, node=node)


def load_config(name: str, overrides: list[str] | tuple[str, ...] = ()) -> DictConfig:
    """Compose `configs/<name>.yaml` with `key=value` overrides; unknown keys raise ConfigError."""
    if not (CONFIG_DIR / f"{name}.yaml").is_file():
        raise ConfigError(f"no config {CONFIG_DIR / name}.yaml; set COSMOS_LITE_CONFIGS to the configs folder")
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base=None):
            cfg = compose(config_name=name, overrides=list(overrides))
    except HydraException as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        detail = str(e.__cause__).splitlines()[0] if e.__cause__ else ""
        cause = f" ({detail})" if detail and detail not in msg else ""
        raise ConfigError(
            f"{msg}{cause}. Run `cosmos-lite {name} --help` for the valid keys "
            "(prefix a new key with + to add it)."
        ) from None
    OmegaConf.set_struct(cfg, True)
    return cfg


def literal(text: str) -> str:
    """`text` escaped so OmegaConf reads it back unchanged (no `${...}` interpolation): for free text such as
    prompts, set into a config after composition."""
    out, i = [], 0
    while (j := text.find("${", i)) >= 0:
        k = j
        while k > i and text[k - 1] == "\\":
            k -= 1
        out += [text[i:k], "\\" * (2 * (j - k) + 1), "${"]
        i = j + 2
    return "".join(out) + text[i:]


# ---------------------------------------------------------------------------------------------------------------
# Checks of single values


def shown(value: Any) -> str:
    """A value as a user typed it, cut to one short line."""
    text = value if isinstance(value, str) and value.strip() else repr(value)
    text = text.replace("\n", " ")
    return text if len(text) <= 200 else text[:197] + "..."


def bad(key: str, value: Any, allowed: str) -> ConfigError:
    """The one error for a bad value: `key=value is not allowed; key takes ALLOWED`."""
    return ConfigError(f"{key}={shown(value)} is not allowed; {key} takes {allowed}")


def number(key: str, value: Any, kind: type = int, low: float | None = None, high: float | None = None,
           above: float | None = None) -> Any:
    """`value` as an int (or float) with `low <= value <= high` and `value > above`; else ConfigError."""
    limits = [f">= {low:g}" if low is not None else "", f"> {above:g}" if above is not None else "",
              f"<= {high:g}" if high is not None else ""]
    allowed = f"{'an integer' if kind is int else 'a number'} {' and '.join(x for x in limits if x)}".strip()
    ok = isinstance(value, int) if kind is int else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok:
        raise bad(key, value, allowed)
    if (low is not None and value < low) or (high is not None and value > high) or \
            (above is not None and value <= above):
        raise bad(key, value, allowed)
    return kind(value)


def choice(key: str, value: Any, choices: Iterable[Any]) -> Any:
    """`value` if it is one of `choices`; else ConfigError listing them."""
    choices = list(choices)
    if value not in choices:
        raise bad(key, value, f"one of {', '.join(map(str, choices))}")
    return value


def output_dir(key: str, path: str | os.PathLike, value: Any = None) -> Path:
    """A folder we can create or write in, checked before any work (nothing is created here); `value`: the path as
    the user gave it, for the message (default: `path`)."""
    p, value = Path(path), str(path if value is None else value)
    if p.exists() and not p.is_dir():
        raise bad(key, value, f"a folder ({p} is an existing file)")
    existing = next(a for a in [p, *p.parents] if a.exists())
    if not existing.is_dir():
        raise bad(key, value, f"a path in a folder ({existing} is a file, not a folder)")
    try:  # a real probe: os.access says yes to root even where nothing can be made (/proc)
        os.rmdir(tempfile.mkdtemp(prefix=".cosmos-lite-probe-", dir=existing))
    except OSError as e:
        raise bad(key, value, f"a writable folder ({existing}: {e.strerror})") from None
    return p


def output_file(key: str, path: str | os.PathLike, suffixes: Iterable[str] = VIDEO_SUFFIXES) -> Path:
    """A file path with one of `suffixes` whose folder we can create or write in, checked before any work."""
    p = Path(path)
    suffixes = tuple(suffixes)
    if p.suffix.lower() not in suffixes:
        raise bad(key, str(path), f"a file name ending in {' or '.join(suffixes)}")
    if p.is_dir():
        raise bad(key, str(path), "a file (that path is an existing folder)")
    output_dir(key, p.parent, path)
    return p


# ---------------------------------------------------------------------------------------------------------------
# Dataclass views of config nodes


def setting(default: Any, *, low: float | None = None, high: float | None = None, above: float | None = None,
            choices: Iterable[Any] | None = None) -> Any:
    """A dataclass field whose value `to_dataclass` checks: `low <= v <= high`, `v > above`, `v in choices`."""
    rules = {k: v for k, v in dict(low=low, high=high, above=above).items() if v is not None}
    if choices is not None:
        rules["choices"] = tuple(choices)
    return dataclasses.field(default=default, metadata={"rules": rules})


def _typed(key: str, value: Any, ann: Any) -> Any:
    """`value` checked against the type annotation `ann` (a scalar where a list is wanted becomes a 1-item list)."""
    origin, params = typing.get_origin(ann), typing.get_args(ann)
    if ann is Any or ann is object:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in params:
            return None
        options = [a for a in params if a is not type(None)]
        lists = [a for a in options if typing.get_origin(a) is list]
        order = lists + [a for a in options if a not in lists] if isinstance(value, list) else \
            [a for a in options if a not in lists] + lists
        errors = []
        for a in order:
            try:
                return _typed(key, value, a)
            except ConfigError as e:
                errors.append(e)
        raise errors[0]
    if dataclasses.is_dataclass(ann):
        return to_dataclass(ann, value, key)
    if ann is bool:
        if not isinstance(value, bool):
            raise bad(key, value, "true or false")
        return value
    if ann in (int, float):
        return number(key, value, ann)
    if ann is str:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return str(value)
        if not isinstance(value, str):
            raise bad(key, value, "a string")
        return value
    if ann is dict or origin is dict:
        if not isinstance(value, dict):
            raise bad(key, value, "a mapping {key: value}")
        return value
    if ann is list or origin is list:
        items = value if isinstance(value, (list, tuple)) else [value]
        item = params[0] if params else Any
        return [_typed(f"{key}[{i}]", v, item) for i, v in enumerate(items)]
    return value


def to_dataclass(cls: type[T], node: DictConfig | dict | T | None, where: str = "") -> T:
    """Build dataclass `cls` from a config node, checking every key: unknown keys, types (from the annotations) and
    the `setting(...)` rules of each field; any failure is a ConfigError naming the key."""
    if isinstance(node, cls):
        return node
    data: dict[str, Any] = (
        OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node or {})
    )
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"unknown config key(s) {', '.join(f'{where}.{k}' if where else k for k in unknown)}; "
            f"valid keys: {', '.join(sorted(fields))}"
        )
    hints = typing.get_type_hints(cls)
    for name, value in data.items():
        key = f"{where}.{name}" if where else name
        value = data[name] = _typed(key, value, hints[name])
        rules = fields[name].metadata.get("rules", {})
        if "choices" in rules:
            choice(key, value, rules["choices"])
        limits = {k: rules[k] for k in ("low", "high", "above") if k in rules}
        if limits and value is not None:
            number(key, value, int if int in (hints[name], *typing.get_args(hints[name])) else float, **limits)
    return cls(**data)


def as_list(value: Any) -> list:
    """A config value that should be a list: a ListConfig or list as a list, one scalar as a one-item list."""
    if isinstance(value, ListConfig):
        return list(OmegaConf.to_container(value, resolve=True))
    if isinstance(value, (list, tuple)):
        return list(value)
    return [] if value is None else [value]
