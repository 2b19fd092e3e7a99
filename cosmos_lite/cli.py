"""`cosmos-lite SUBCOMMAND [ARG ...] key=value ...`: Hydra overrides composed from `configs/`.

Each subcommand is a module with `main(cfg, args) -> int | None` and a config
`configs/<subcommand>.yaml`. Exit codes (DESIGN.md): 0 ok, 2 bad arguments or config,
3 blocked by a guardrail, 4 unreadable input, 1 anything else (one line; the traceback
with COSMOS_LITE_DEBUG=1). Free-text keys (`prompt=...`) take the rest of their argument
verbatim; `-m` runs each job of a sweep in its own OUT/N folder and lists them.
"""

from __future__ import annotations

import difflib
import importlib
import itertools
import json
import os
import shutil
import sys
import traceback
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .config import CONFIG_DIR, literal, load_config, output_dir, output_file
from .errors import ConfigError, CosmosError
from .log import debugging, get_logger, setup_logging

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

# Keys whose value is free text: passed verbatim, never through Hydra's override grammar.
FREE_TEXT = ("prompt", "generate.prompt", "generate.blocked_prompt")
# The paths each subcommand writes (checked before it runs; a sweep gives each job its own): key -> dir | file.
OUTPUTS: dict[str, dict[str, str]] = {
    "sim": {"out": "dir"}, "curate": {"output": "dir"}, "train": {"out": "dir"}, "generate": {"output": "dir"},
    "eval": {"out": "dir"}, "demo": {"out": "dir"}, "tokenize": {"output": "file"}, "guard": {"blur_out": "file"},
}
_ABSENT = object()
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


def split_free_text(args: list[str]) -> tuple[list[str], dict[str, str]]:
    """Take `KEY=TEXT` for the free-text keys out of `args` before Hydra's override grammar sees them: the text
    after the first `=` is the value, verbatim (commas, quotes, brackets, `#`, `=`, any script)."""
    rest, texts = [], {}
    for a in args:
        key, sep, value = a.partition("=")
        if sep and key in FREE_TEXT:
            texts[key] = value
        else:
            rest.append(a)
    return rest, texts


def set_free_text(cfg: DictConfig, texts: dict[str, str], name: str) -> None:
    """Set each free text into the composed config, escaped so OmegaConf never reads `${...}` in it."""
    for key, text in texts.items():
        if OmegaConf.select(cfg, key, default=_ABSENT) is _ABSENT:
            raise ConfigError(f"{key}= is not a key of `cosmos-lite {name}`; see `cosmos-lite {name} --help`")
        OmegaConf.update(cfg, key, literal(text), merge=False)


def check_added_keys(name: str, overrides: list[str]) -> None:
    """`+KEY=VALUE` adds entries to a mapping (`+sim.params.radius=4`); at the top level no code would read a new key,
    so `+num_frame=9` is a misspelling and refused (nested nodes check their own keys where they are read)."""
    base = None
    for key in [o.lstrip("+").partition("=")[0] for o in overrides if o.startswith("+")]:
        if "." in key:
            continue
        base = base or load_config(name, [o for o in overrides if not o.startswith("+")])
        close = difflib.get_close_matches(key, [str(k) for k in base.keys()], n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        raise ConfigError(f"+{key}: `cosmos-lite {name}` has no key {key} and would ignore it; {hint}"
                          f"(see `cosmos-lite {name} --help`)")


def _outputs(name: str, cfg: DictConfig) -> dict[str, tuple[Path, str]]:
    """The output paths this run of `name` writes: key -> (path, "dir" | "file")."""
    found = {}
    for key, kind in OUTPUTS.get(name, {}).items():
        value = OmegaConf.select(cfg, key, default=None)
        if value not in (None, ""):
            found[key] = (Path(str(value)), kind)
    return found


def _job_outputs(cfg: DictConfig, outputs: dict[str, tuple[Path, str]], job: int) -> dict[str, tuple[Path, str]]:
    """Give sweep job `job` its own output: OUT/JOB for folders (Hydra's sweep layout), OUT-JOB.ext for files."""
    moved = {}
    for key, (path, kind) in outputs.items():
        new = path / str(job) if kind == "dir" else path.with_name(f"{path.stem}-{job}{path.suffix}")
        OmegaConf.update(cfg, key, str(new), merge=False)
        moved[key] = (new, kind)
    return moved


def _new_root(path: Path) -> Path | None:
    """The topmost folder of `path` that does not exist yet (None if `path` exists): what a run would create."""
    if path.exists():
        return None
    return next(a for a in [*reversed(path.parents), path] if not a.exists())


def _remove_if_empty(root: Path | None) -> None:
    """Remove `root` when a failed run left it without any file (folders it created and never filled)."""
    if root is not None and root.is_dir() and not any(p.is_file() for p in root.rglob("*")):
        shutil.rmtree(root, ignore_errors=True)


def run_job(name: str, module, cfg: DictConfig, args: list[str], outputs: dict[str, tuple[Path, str]]) -> int:
    """Check the outputs are writable, run the subcommand, and leave no empty output folder if it fails."""
    for key, (path, kind) in outputs.items():
        output_dir(key, path) if kind == "dir" else output_file(key, path)
    roots = [_new_root(path if kind == "dir" else path.parent) for path, kind in outputs.values()]
    try:
        code = module.main(cfg, args) or 0
    except BaseException:
        for root in roots:
            _remove_if_empty(root)
        raise
    if code:
        for root in roots:
            _remove_if_empty(root)
    return code


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
    rest, texts = split_free_text(rest)
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
    check_added_keys(name, runs[0])
    jobs = [load_config(name, ov) for ov in runs]  # every job's config is checked before the first one runs
    for cfg in jobs:
        set_free_text(cfg, texts, name)
    if show_cfg:
        for cfg in jobs:
            print(OmegaConf.to_yaml(cfg, resolve=True))
        return 0
    if not multirun:
        return run_job(name, module, jobs[0], args, _outputs(name, jobs[0]))
    summary, code = [], 0
    for i, (ov, cfg) in enumerate(zip(runs, jobs)):
        outputs = _job_outputs(cfg, _outputs(name, cfg), i)
        log.info("multirun job %d/%d: %s", i + 1, len(runs), " ".join(ov))
        try:
            job_code = run_job(name, module, cfg, args, outputs)
        except CosmosError as e:
            print(f"cosmos-lite: error: job {i} ({' '.join(ov)}): {e}", file=sys.stderr)
            job_code = e.exit_code
        code = max(code, job_code)
        summary.append({"job": i, "overrides": ov, "exit": job_code, **{k: str(p) for k, (p, _) in outputs.items()}})
    bases = {Path(job[k]).parent for job in summary for k, kind in OUTPUTS.get(name, {}).items()
             if kind == "dir" and k in job and Path(job[k]).is_dir()}
    for base in bases:  # the sweep's summary beside its job folders, as Hydra's multirun.yaml
        tmp = base / ".multirun.json.tmp"
        tmp.write_text(json.dumps({"subcommand": name, "jobs": summary}, indent=1) + "\n")
        tmp.replace(base / "multirun.json")
    print(json.dumps({"multirun": summary}))
    return code


def main(argv: list[str] | None = None) -> int:
    """Console entry point: maps errors to exit codes and clear one-line messages."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    setup_logging()
    try:
        code = run(sys.argv[1:] if argv is None else argv)
    except KeyboardInterrupt:
        print("cosmos-lite: interrupted", file=sys.stderr)
        code = 130
    except Exception as e:  # noqa: BLE001 - every failure ends in one line (the traceback on request)
        if debugging():
            traceback.print_exc()
        if isinstance(e, CosmosError):
            msg, code = str(e), e.exit_code
        elif isinstance(e, OmegaConfBaseException):
            msg, code = f"config: {str(e).splitlines()[0]} (configs in {CONFIG_DIR})", ConfigError.exit_code
        else:
            msg, code = (f"unexpected {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''} "
                         "(rerun with COSMOS_LITE_DEBUG=1 for the traceback, and please report it)"), 1
        print(f"cosmos-lite: error: {' '.join(msg.split())}", file=sys.stderr)
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
