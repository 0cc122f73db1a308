"""What the `python -m samp.X COMMAND key=value ...` entry points share: one command-line dialect.

Every entry point takes a subcommand (where it has several), then `key=value` options; the natural
subject of a command (a run folder, a dataset) may also be given bare. `-h` / `--help` prints the usage
on stdout and exits 0; no arguments or an unknown command print it on stderr and exit 2, and so does
bad input, as a one-line error instead of a traceback. Helpers here compose Hydra configs (`+group=`
and `group=` alike for the groups a config's defaults list names), list what a config folder offers for
the help texts, parse `key=value` options (older `--flag value` spellings stay accepted), and print a
composed config resolved where possible.
"""

from __future__ import annotations

import re
import sys
import textwrap
from functools import lru_cache
from pathlib import Path
from typing import Callable

__all__ = ["HELP_FLAGS", "canonical_overrides", "command_help", "compose", "config_names", "config_yaml",
           "default_groups", "describe", "output_path", "parse_options", "run_command", "settings_help",
           "wants_help", "wrap"]

HELP_FLAGS = ("-h", "--help")


def wants_help(argv: list[str]) -> bool:
    """`-h` / `--help` anywhere, or `help` as the command."""
    return any(a in HELP_FLAGS for a in argv) or argv[:1] == ["help"]


@lru_cache(maxsize=None)
def default_groups(config_name: str) -> dict[str, str | None]:
    """The config groups named by conf/<config_name>.yaml's defaults list, with their default option."""
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    path = conf_dir() / f"{config_name}.yaml"
    raw = OmegaConf.to_container(OmegaConf.load(path)) if path.is_file() else {}
    groups: dict[str, str | None] = {}
    for entry in raw.get("defaults") or []:
        if isinstance(entry, dict):
            for key, value in entry.items():  # "robot: panda", "override /model: x", "optional x@pkg: y"
                groups[key.split()[-1].lstrip("/").partition("@")[0]] = value
    return groups


def canonical_overrides(config_name: str, overrides: list[str]) -> list[str]:
    """`+group=option` written `group=option` for the groups the config's defaults list already names:
    Hydra refuses to add such a group a second time ("Multiple values for experiment"), so both spellings
    mean the same. Every other override is kept as it is."""
    groups = default_groups(config_name)
    out = []
    for o in overrides:
        key = o.partition("=")[0]
        out.append(o[1:] if key.startswith("+") and not key.startswith("++") and key[1:] in groups else o)
    return out


def compose(config_name: str, overrides: list[str], return_hydra_config: bool = False):
    """Compose `conf/<config_name>.yaml` with command-line overrides (`key=value`, `group=option`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    from samp.paths import conf_dir

    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=canonical_overrides(config_name, list(overrides)),
                             return_hydra_config=return_hydra_config)


def output_path(out: str | Path) -> Path:
    """An output file path; relative paths are taken from the project folder (the clone, or `SAMP_HOME`, or
    the current folder: `samp.paths.project_dir`). Its folder is created."""
    from samp.paths import project_dir

    path = Path(out)
    path = path if path.is_absolute() else project_dir() / path
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def run_command(argv: list[str] | None, usage: str | Callable[[], str],
                commands: dict[str, Callable[[list[str]], object]]) -> int:
    """Dispatch `argv[0]` to `commands`, passing the remaining arguments. `--help`: the usage on stdout, 0;
    no command or an unknown one: the usage on stderr, 2; bad input: a one-line error on stderr, 2."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    argv = sys.argv[1:] if argv is None else argv
    text = usage if isinstance(usage, str) else None
    if wants_help(argv):
        print(text or usage())
        return 0
    if not argv or argv[0] not in commands:
        if argv:
            print(f"error: unknown command {argv[0]!r}; commands: {', '.join(commands)}", file=sys.stderr)
        print(text or usage(), file=sys.stderr)
        return 2
    try:
        commands[argv[0]](argv[1:])
    except (HydraException, OmegaConfBaseException, ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


# --- help texts, computed from the config folder ---------------------------------------------------------

def config_names(group: str) -> list[str]:
    """The options of a config group: the names of conf/<group>/*.yaml, sorted."""
    from samp.paths import conf_dir

    return sorted(p.stem for p in (conf_dir() / group).glob("*.yaml"))


def describe(group: str, name: str, width: int = 72) -> str:
    """The first comment line of conf/<group>/<name>.yaml (after `# @package`), shortened to `width`; a
    config from the user's own folders (`SAMP_CONFIG_PATH`) is marked `[yours]`."""
    from samp.paths import conf_dir, user_config

    path = conf_dir() / group / f"{name}.yaml"
    mark = "[yours] " if user_config(path) else ""
    for line in path.read_text().splitlines():
        if line.startswith("#") and not line.startswith("# @package"):
            return textwrap.shorten(mark + line.lstrip("# ").rstrip(":"), width, placeholder=" ...")
        if line.strip() and not line.startswith("#"):
            break
    return mark.strip()


def wrap(items: list[str], indent: str = "  ", width: int = 100) -> str:
    """`items` separated by two spaces, wrapped at `width` between items, never inside one."""
    nbsp = "\u00a0"  # textwrap breaks at ASCII whitespace only
    text = textwrap.fill("  ".join(i.replace(" ", nbsp) for i in items if i), width, initial_indent=indent,
                         subsequent_indent=indent, break_on_hyphens=False, break_long_words=False)
    return text.replace(nbsp, " ")


_SETTING = re.compile(r"^([A-Za-z_]\w*):[ \t]*([^#\n]*?)[ \t]*(?:#[ \t]*(.*))?$")


def _settings(config_name: str, skip: tuple[str, ...] = ("defaults", "hydra")) -> list[tuple[str, str]]:
    """(`key=default`, comment) for each top-level setting of conf/<config_name>.yaml, read from the file
    itself (so the help says what the config says)."""
    from samp.paths import conf_dir

    rows: list[tuple[str, str]] = []
    for line in (conf_dir() / f"{config_name}.yaml").read_text().splitlines():
        match = _SETTING.match(line)
        more = re.match(r"^\s+#\s*(.*)$", line)
        if more and rows and rows[-1][1]:  # a comment continued on the next line
            rows[-1] = (rows[-1][0], f"{rows[-1][1]} {more.group(1)}")
        elif match and match.group(1) not in skip:
            key, value, comment = match.groups()
            rows.append((f"{key}={value}" if value else f"{key}.KEY=...", comment or ""))
    return rows


def _table(rows: list[tuple[str, str]], indent: str, width: int = 110) -> str:
    """Two columns, the second wrapped; a first column longer than 26 characters pushes its comment right."""
    col = min(max((len(k) for k, _ in rows), default=0), 26)
    pad = " " * (len(indent) + col + 3)
    return "\n".join(textwrap.fill(f"{indent}{k:<{col}}   {c}".rstrip(), width, subsequent_indent=pad,
                                   break_long_words=False, break_on_hyphens=False) for k, c in rows)


def settings_help(config_name: str, indent: str = "  ") -> str:
    """The top-level settings of conf/<config_name>.yaml as `key=default   comment` lines."""
    return _table(_settings(config_name), indent)


def command_help(config_name: str, indent: str = "  ") -> str:
    """The `key=default` settings of a command composed from conf/<config_name>.yaml: each group of its
    defaults list with its options (conf/GROUP/), then its own settings."""
    groups = [(f"{g}={d}", f"or {', '.join(o for o in config_names(g) if o != d)} (conf/{g}/)")
              for g, d in default_groups(config_name).items()]
    return _table([*groups, *_settings(config_name)], indent)


# --- key=value options --------------------------------------------------------------------------------------

def _is_option(token: str, keys) -> bool:
    return "=" in token and token.partition("=")[0] in keys


def _split_list(value: str) -> list[str]:
    """`a,b`, `[a,b]` or `a` -> the values."""
    value = value.strip()
    if value.startswith("[") and value.endswith("]"):
        value = value[1:-1]
    return [v.strip().strip("'\"") for v in value.split(",") if v.strip()]


def parse_options(args: list[str], keys: tuple[str, ...], lists: tuple[str, ...] = (), filters: bool = False,
                  positional: str | None = None, command: str = "") -> tuple[list[str], dict, list[str]]:
    """Split a command's arguments into (bare arguments, options, filters).

    `keys` are the command's options, given as `key=value`; those in `lists` take several values
    (`key=a,b` or `key=[a,b]`). The older spellings `--key value` and `--key=value` (several values after a
    list's flag) are read the same. Any other `KEY=VALUE` is a filter when `filters`, else an error naming
    the options, unless it names an existing path or holds a `/` (run folders may be named `a=1,b=2`):
    then it is a bare argument, as every argument without `=` is when `positional` (the bare argument's
    name in messages) is set."""
    bare, opts, extra = [], {}, []
    i = 0
    while i < len(args):
        token = args[i]
        i += 1
        if token.startswith("--") and len(token) > 2:
            key, eq, value = token[2:].partition("=")
            key = key.replace("-", "_")
            if key not in keys:
                raise ValueError(f"unknown option {token!r}{f' for {command}' if command else ''}; options: "
                                 + ", ".join(f"{k}=..." for k in keys))
            values = [value] if eq else []
            while not eq and i < len(args) and not args[i].startswith("-"):
                if values and (key not in lists or "=" in args[i]):  # a list's values end at the next key=value
                    break
                values.append(args[i])
                i += 1
            if not values:
                raise ValueError(f"{token} needs a value ({key}=VALUE)")
            opts[key] = [v for x in values for v in _split_list(x)] if key in lists else values[0]
        elif _is_option(token, keys):
            key, _, value = token.partition("=")
            opts[key] = _split_list(value) if key in lists else value
        elif "=" in token and not (positional and ("/" in token.partition("=")[0] or Path(token).exists())):
            if not filters:
                raise ValueError(f"unknown option {token.partition('=')[0]!r}{f' for {command}' if command else ''}; "
                                 "options: " + ", ".join(f"{k}=..." for k in keys))
            extra.append(token)
        elif positional:
            bare.append(token)
        else:
            raise ValueError(f"unexpected argument {token!r}{f' for {command}' if command else ''}; options: "
                             + ", ".join(f"{k}=..." for k in keys))
    return bare, opts, extra


# --- printing a composed config ------------------------------------------------------------------------------

def _resolved(node, raw):
    """`node` as plain containers, each interpolation resolved where it can be and kept as written where
    it cannot (a `${hydra:...}` outside a Hydra app, a value still `???`)."""
    from omegaconf import DictConfig, ListConfig, OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    try:
        return OmegaConf.to_container(node, resolve=True, throw_on_missing=True)
    except OmegaConfBaseException:
        pass
    if not isinstance(node, (DictConfig, ListConfig)):
        return raw
    out = {} if isinstance(node, DictConfig) else [None] * len(raw)
    for key in (node.keys() if isinstance(node, DictConfig) else range(len(node))):
        try:
            child = node[key]
        except OmegaConfBaseException:
            out[key] = raw[key]
            continue
        out[key] = _resolved(child, raw[key]) if isinstance(child, (DictConfig, ListConfig)) else child
    return out


def config_yaml(cfg, resolve: bool | None = None) -> str:
    """The config as YAML: `resolve=None` resolves what can be resolved, True all of it (or raises), False
    nothing."""
    from omegaconf import OmegaConf

    if resolve is not None:
        return OmegaConf.to_yaml(cfg, resolve=resolve)
    return OmegaConf.to_yaml(OmegaConf.create(_resolved(cfg, OmegaConf.to_container(cfg, resolve=False))))
