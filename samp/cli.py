"""What the `python -m samp.X COMMAND key=value ...` entry points share: one command-line dialect.

Every entry point takes a subcommand (where it has several), then `key=value` options; the natural
subject of a command (a run folder, a dataset) may also be given bare. `-h` / `--help` prints the usage
on stdout and exits 0; no arguments or an unknown command print it on stderr and exit 2, and so does
bad input, as a one-line error instead of a traceback. Helpers here compose Hydra configs (`+group=`
and `group=` alike for the groups a config's defaults list names), list what a config folder offers for
the help texts, parse `key=value` options (older `--flag value` spellings stay accepted), and print a
composed config resolved where possible.

samp composes with Hydra's API, not through Hydra's application, so Hydra's own flags are answered here:
`--hydra-help` is samp's help, `--info` says which config folders samp reads (`config_info`), and the
rest (`--package`, `--config-dir`, ...) are refused with what samp offers instead. Every override is
parsed before composing, so a bad one is named on one line, and `hydra.run.dir`, which no samp command
reads, is refused with the key that names the folder instead.
"""

from __future__ import annotations

import errno
import math
import os
import re
import shlex
import sys
import textwrap
from functools import lru_cache
from pathlib import Path
from typing import Callable

__all__ = ["HELP_FLAGS", "INFO_FLAG", "answer_help", "canonical_overrides", "check_finite", "check_override_syntax",
           "command_help", "compose", "config_info", "config_names", "config_yaml", "default_groups", "describe", "flag", "help_or_info",
           "output_path", "parse_options", "paste", "run_command", "settings_help", "user_error", "wants_help", "wrap"]

HELP_FLAGS = ("-h", "--help", "--hydra-help")  # Hydra's help flag gets samp's help: samp's own options are the ones
INFO_FLAG = "--info"  # Hydra's `--info [searchpath|defaults|...]`: here, the config folders samp reads


def wants_help(argv: list[str]) -> bool:
    """`-h` / `--help` / `--hydra-help` / `--info` anywhere, or `help` as the command."""
    return any(a in HELP_FLAGS for a in argv) or _wants_info(argv) or argv[:1] == ["help"]


def _wants_info(argv: list[str]) -> bool:
    return any(a == INFO_FLAG or a.startswith(INFO_FLAG + "=") for a in argv)


def help_or_info(argv: list[str], usage: str | Callable[[], str]) -> str:
    """What a help request prints: `config_info()` for `--info` (unless a help flag is given too), else the
    usage (a text, or a function computing it)."""
    if _wants_info(argv) and not any(a in HELP_FLAGS for a in argv):
        return config_info()
    return usage if isinstance(usage, str) else usage()


def answer_help(argv: list[str], usage: str | Callable[[], str]) -> int:
    """Print what `argv` asks for when it asks for help (`help_or_info`) on stdout and return 0, or, for no
    arguments, the usage on stderr and 2. The help lists the user's config folders, so a folder that cannot
    be read is an error of the user's: its one line on stderr, 2."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        text = help_or_info(argv, usage)
    except (HydraException, OmegaConfBaseException, ValueError, OSError) as err:
        message = user_error(err)
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2
    from samp.console import as_installed  # the commands and config folder of this install

    print(as_installed(text), file=sys.stdout if argv else sys.stderr)
    return 0 if argv else 2


def config_info() -> str:
    """The config folders samp reads, in the order a file is looked for, where Hydra composes from, and
    which of samp's files the user's folders shadow (Hydra's `--info searchpath` for samp)."""
    from samp.config_overlay import overlay
    from samp.paths import cache_dir, config_path, packaged_conf_dir

    own, user = packaged_conf_dir(), config_path()
    lines = ["config folders, in the order a file is looked for (the first folder that has it wins):"]
    lines += [f"  {folder}   (SAMP_CONFIG_PATH)" for folder in user]
    lines += [f"  {own}   (samp's own{', from SAMP_CONF_DIR' if os.environ.get('SAMP_CONF_DIR') else ''})"]
    if user:
        view, shadowed = overlay([*user, own], cache_dir("config"), trusted=(own,))
        lines += ["", f"Hydra composes from their merged view: {view} (links to the files above)"]
        lines += ["", "your files in place of samp's:" if shadowed else "no file of yours replaces one of samp's"]
        lines += [f"  {line}" for line in shadowed]
    lines += ["", "`python -m samp.train experiment=NAME --cfg job` prints a composed config; --help lists the options"]
    return "\n".join(lines)


@lru_cache(maxsize=None)
def default_groups(config_name: str) -> dict[str, str | None]:
    """The config groups named by conf/<config_name>.yaml's defaults list, with their default option."""
    from omegaconf import OmegaConf

    from samp.paths import conf_dir, shown_path
    from samp.yaml_files import load_config

    path = conf_dir() / f"{config_name}.yaml"
    raw = OmegaConf.to_container(load_config(shown_path(path))) if path.is_file() else {}
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
    """Compose `conf/<config_name>.yaml` with command-line overrides (`key=value`, `group=option`); every float
    of the result must be finite (`check_finite`)."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    check_override_syntax(config_name, overrides)
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        cfg = hydra_compose(config_name=config_name, overrides=canonical_overrides(config_name, list(overrides)),
                            return_hydra_config=return_hydra_config)
    check_finite(_resolved(cfg, OmegaConf.to_container(cfg, resolve=False)))
    return cfg


# Hydra application flags (`python app.py --flag`) that samp's command lines do not take, and what to use instead
_FOLDERS = ("samp reads its configs from its own conf/ and the folders of SAMP_CONFIG_PATH: put your folder in "
            "SAMP_CONFIG_PATH (docs/bring-your-own.md)")
_HYDRA_FLAGS = {
    ("--package", "-p"): "samp does not select a package of the printed config: print it whole with --cfg job "
                         "(python -m samp.train) and read the node you need",
    ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd"): _FOLDERS,
    ("--multirun", "-m", "--run", "-r"): "only python -m samp.train takes -m (a sweep); a single run needs no flag",
    ("--shell-completion", "-sc", "--experimental-rerun", "--version"): "samp's command lines do not offer it",
}
_OVERRIDES = "key=value, GROUP=OPTION, +key=value or ~key"
_FLAGS = "--help and --info (python -m samp.train also takes -m and --cfg job|hydra|all)"
# Where each command puts what Hydra's run folder would hold: samp makes its own folders
_OUTPUT_KEY = {"train": "run_dir=DIR (python -m samp.train; default runs/EXPERIMENT/TIMESTAMP/ under SAMP_RUNS_DIR)",
               "eval": "out=DIR (default RUN_DIR/eval/)", "data": "root=DIR (default datasets/ or SAMP_DATASETS_DIR)"}


def check_override_syntax(config_name: str, overrides: list[str]) -> None:
    """Each command-line override parsed as Hydra will parse it, so that a bad one is named on one line
    (Hydra's own error spans three lines and, for a flag it does not know, names only a lexer exception);
    Hydra's application flags and `hydra.run.*`, which samp's commands never read, are refused with what
    to use instead."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    for o in overrides:
        if o.startswith("-"):
            flag_name = o.partition("=")[0]
            answer = next((a for flags, a in _HYDRA_FLAGS.items() if flag_name in flags), None)
            raise ValueError(f"{flag_name} {'is a flag of Hydra applications' if answer else 'is not an option'}"
                             f"{'; ' + answer if answer else ''}; samp's command lines take {_OVERRIDES}, and the "
                             f"flags {_FLAGS}")
        try:
            key = parser.parse_override(o).key_or_group
        except HydraException as err:  # parse_override raises the base class, parse_overrides a subclass
            reason = str(err).splitlines()[0] if str(err) else type(err).__name__
            raise ValueError(f"override {o!r} is not valid: {reason}; write {_OVERRIDES}, and quote a value that "
                             "holds spaces, brackets, commas or '=' (key='[1, 2]')") from None
        if key == "hydra.run" or key.startswith("hydra.run."):
            where = _OUTPUT_KEY.get(config_name, "the command's own output option (--help lists it)")
            raise ValueError(f"{o!r} has no effect: samp does not run through Hydra's application, so no command "
                             f"reads hydra.run.*; choose the output folder with {where}")


def check_finite(node, path: str = "") -> None:
    """Every float of a config (plain containers) must be finite: `lr=nan` would pass every range check (a
    NaN compares false) and fail much later without naming the key."""
    if isinstance(node, dict):
        for key, value in node.items():
            check_finite(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            check_finite(value, f"{path}[{i}]")
    elif isinstance(node, float) and not math.isfinite(node):
        raise ValueError(f"config key {path}={node!r} is not a finite number; give a finite value")


def paste(command: str, *args, **options) -> str:
    """A command line for a user to paste: `command` (fixed words of ours) followed by each argument and
    `key=value` option shell-quoted, so a name holding `;`, spaces or quotes is one word, never shell code."""
    words = [*map(str, args), *(f"{key}={value}" for key, value in options.items())]
    return " ".join([command, *(shlex.quote(w) for w in words)])


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
    if wants_help(argv):
        return answer_help(argv, usage)
    if not argv or argv[0] not in commands:
        if argv:
            print(f"error: unknown command {argv[0]!r}; commands: {', '.join(commands)}", file=sys.stderr)
        answer_help([], usage)
        return 2
    try:
        commands[argv[0]](argv[1:])
    except (HydraException, OmegaConfBaseException, ValueError, OSError) as err:
        message = user_error(err)
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2
    return 0


# errno -> what went wrong with the path, and what to do about it
_ENVIRONMENT = {
    errno.ENOSPC: ("no space is left on the disk of", "free space there, or point the output elsewhere (root=DIR or "
                   "SAMP_DATASETS_DIR / SAMP_RUNS_DIR / SAMP_CACHE_DIR) and run again"),
    errno.EDQUOT: ("the disk quota is exhausted for", "free space there, or point the output elsewhere and run again"),
    errno.EFBIG: ("a file grew past the size this system allows (ulimit -f) at", "raise the limit or write elsewhere"),
    errno.EROFS: ("the file system is read-only at", "write to a folder you can write (root=DIR, or SAMP_*_DIR)"),
    errno.EACCES: ("permission denied for", "write to a folder you can write (root=DIR, or SAMP_*_DIR), or fix its "
                   "permissions"),
    errno.EPERM: ("the operation is not permitted on", "use a folder you own (root=DIR, or SAMP_*_DIR)"),
    errno.ENAMETOOLONG: ("a name is too long for the file system in", "choose a shorter name (most file systems allow "
                         "255 bytes a name)"),
    errno.ENOTDIR: ("a file stands where a folder is needed in", "point the path (or SAMP_*_DIR) at a folder, or move "
                    "the file away"),
    errno.EISDIR: ("a folder stands where a file is needed at", "give a file path"),
    errno.EEXIST: ("something already exists at", "move it away, or choose another path"),
    errno.ENOENT: ("no such file or folder:", "check the path, or create the folder"),
}


def user_error(err: BaseException) -> str | None:
    """The one line to print for an error of the user's input or environment (exit 2), or None for a bug
    (which keeps its traceback). An OSError of the environment (disk full, read-only, a name too long, a
    file where a folder belongs) names the path and what to do."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(err, (HydraException, OmegaConfBaseException, ValueError)):  # Hydra's missing config is an IOError
        return str(err)
    if not isinstance(err, OSError):
        return None
    if err.errno is None:  # raised by samp itself (a missing config folder, SAMP_HOME a file): its message says it all
        return str(err)
    if err.errno not in _ENVIRONMENT:
        return None
    what, todo = _ENVIRONMENT[err.errno]
    paths = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None) or "(a path not given)"
    return f"{what} {paths} ({err.strerror}); {todo}"


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

def flag(key: str, value: str) -> bool:
    """A `key=true|false` option's value (also 1/0, yes/no); ValueError naming the key otherwise."""
    text = str(value).strip().lower()
    if text in ("true", "1", "yes"):
        return True
    if text in ("false", "0", "no"):
        return False
    raise ValueError(f"{key}={value!r}: give {key}=true or {key}=false")


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
