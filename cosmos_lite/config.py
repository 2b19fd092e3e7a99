"""Hydra config composition from the `configs/` tree, and dataclass views of config nodes."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, TypeVar

from hydra import compose, initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf

from .errors import ConfigError

T = TypeVar("T")

CONFIG_DIR = Path(os.environ.get("COSMOS_LITE_CONFIGS", Path(__file__).resolve().parent.parent / "configs"))


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


def to_dataclass(cls: type[T], node: DictConfig | dict | None, where: str = "") -> T:
    """Build dataclass `cls` from a config node; an unknown key raises ConfigError naming it."""
    data: dict[str, Any] = (
        OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node or {})
    )
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"unknown config key(s) {', '.join(f'{where}.{k}' if where else k for k in unknown)}; "
            f"valid keys: {', '.join(sorted(names))}"
        )
    return cls(**data)
