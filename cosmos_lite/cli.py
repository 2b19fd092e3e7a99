"""`cosmos-lite SUBCOMMAND [ARG ...] key=value ...`: Hydra overrides composed from `configs/`.

Each subcommand is a module with `main(cfg, args) -> int | None` and a config
`configs/<subcommand>.yaml`. Exit codes (DESIGN.md): 0 ok, 2 bad arguments or config,
3 blocked by a guardrail, 4 unreadable input, 1 anything else.
"""

from __future__ import annotations

import importlib
import itertools
import os
import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .config import CONFIG_DIR, load_config
from .errors import ConfigError, CosmosError
from .log import get_logger, setup_logging

# name -> (module with main(cfg, args), one-line help). Listed once its module exists.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("cosmos_lite.sim.cli", "simulate physics episodes (mp4 + masks, states, actions, caption)"),
    "curate": ("cosmos_lite.curation.cli", "split, filter and transcode raw video into clips (local or Ray)"),
    "train": ("cosmos_lite.train", "train a model: experiment=tokenizer_nano | wfm_nano | frame_classifier"),
    "tokenize": ("cosmos_lite.tokenizers.cli", "encode and decode a video with a tokenizer; print PSNR/SSIM"),
    "generate": ("cosmos_lite.models.cli", "generate guarded videos from a prompt, first frames and actions"),
    "guard": ("cosmos_lite.guardrails.cli", "check a prompt or a video against the guardrails"),
    "eval": ("cosmos_lite.eval.cli", "physics-alignment benchmark and reports; compare two results"),
    "demo": ("cosmos_lite.demo", "the whole pipeline end to end on a small embedded default"),
    "probe": ("cosmos_lite.probe", "print a video's fps, frame count, size, codec and duration as JSON"),
}

USAGE = "usage: cosmos-lite [--help] SUBCOMMAND [ARG ...] [key=value ...] [--cfg job] [-m]"
log = get_logger("cli")


def available() -> dict[str, tuple[str, str]]:
    """The subcommands whose module exists (found by path, so --help imports nothing heavy)."""
    root = Path(__file__).resolve().parent.parent
    return {k: v for k, v in SUBCOMMANDS.items() if (root / (v[0].replace(".", "/") + ".py")).is_file()}


def _top_help() -> str:
    lines = [USAGE, "", "World foundation models for physical AI, end to end on a CPU.", "", "subcommands:"]
    lines += [f"  {name:<10}{text}" for name, (_, text) in available().items()]
    lines += [
        "",
        "Run `cosmos-lite SUBCOMMAND --help` to see its configuration; override any key with",
        "key=value, print the resolved config with --cfg job, sweep comma-separated values with -m.",
    ]
    return "\n".join(lines)


def _sub_help(name: str, module) -> str:
    doc = (module.__doc__ or "").strip()
    try:
        text = OmegaConf.to_yaml(load_config(name))
    except ConfigError:  # e.g. a mandatory group choice such as experiment=???
        text = (CONFIG_DIR / f"{name}.yaml").read_text()
    groups = sorted(d for d in CONFIG_DIR.iterdir() if d.is_dir())
    options = [f"  {d.name}: {', '.join(sorted(f.stem for f in d.glob('*.yaml')))}" for d in groups]
    return (
        f"cosmos-lite {name}: {SUBCOMMANDS[name][1]}\n\n{doc}\n\nconfig (configs/{name}.yaml):\n{text}\n"
        "config groups (choose with group=option):\n" + "\n".join(options)
    )


def _sweep(overrides: list[str]) -> list[list[str]]:
    """Expand comma-separated sweep overrides (`lr=1e-3,1e-4`) into the list of runs."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    choices = []
    for o in parsed:
        key = o.get_key_element()
        values = list(o.sweep_string_iterator()) if o.is_sweep_override() else [o.get_value_element_as_str()]
        choices.append([f"{key}={v}" for v in values])
    return [list(run) for run in itertools.product(*choices)]


def run(argv: list[str]) -> int:
    """Parse argv, compose the config and run the subcommand; returns the exit code."""
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(_top_help())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    subs = available()
    if name not in subs:
        raise ConfigError(f"unknown subcommand {name!r}; choose one of: {', '.join(subs)}")
    module = importlib.import_module(subs[name][0])
    if "-h" in rest or "--help" in rest:
        print(_sub_help(name, module))
        return 0
    show_cfg = False
    if "--cfg" in rest:
        i = rest.index("--cfg")
        if rest[i + 1 : i + 2] != ["job"]:
            raise ConfigError("--cfg takes `job`: `cosmos-lite SUB ... --cfg job`")
        show_cfg, rest = True, rest[:i] + rest[i + 2 :]
    multirun = any(a in ("-m", "--multirun") for a in rest)
    rest = [a for a in rest if a not in ("-m", "--multirun")]
    flags = [a for a in rest if a.startswith("-")]
    if flags:
        raise ConfigError(f"unknown option(s) {' '.join(flags)}; see `cosmos-lite {name} --help`")
    overrides = [a for a in rest if "=" in a]
    args = [a for a in rest if "=" not in a]
    runs = _sweep(overrides) if multirun else [overrides]
    code = 0
    for i, ov in enumerate(runs):
        cfg: DictConfig = load_config(name, ov)
        if show_cfg:
            print(OmegaConf.to_yaml(cfg, resolve=True))
            continue
        if multirun:
            log.info("multirun %d/%d: %s", i + 1, len(runs), " ".join(ov))
        code = max(code, module.main(cfg, args) or 0)
    return code


def main(argv: list[str] | None = None) -> int:
    """Console entry point: maps errors to exit codes and clear one-line messages."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    setup_logging()
    try:
        code = run(sys.argv[1:] if argv is None else argv)
    except CosmosError as e:
        print(f"cosmos-lite: error: {e}", file=sys.stderr)
        code = e.exit_code
    except OmegaConfBaseException as e:
        msg = str(e).splitlines()[0]
        print(f"cosmos-lite: error: config: {msg} (configs in {CONFIG_DIR})", file=sys.stderr)
        code = ConfigError.exit_code
    except KeyboardInterrupt:
        print("cosmos-lite: interrupted", file=sys.stderr)
        code = 130
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
