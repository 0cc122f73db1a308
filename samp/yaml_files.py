"""Reading YAML a user wrote (config folders, dataset specs, scene files) with bounded cost.

YAML anchors and aliases let a few hundred bytes stand for billions of nodes: PyYAML itself shares the
aliased node, but everything after it (OmegaConf building a config, `asdict`, hashing a spec) copies it
out, and never finishes. So before a file is handed to PyYAML or OmegaConf, its event stream is walked once
(linear in the file's bytes, no recursion) to bound what it expands to:

- the file itself: at most `MAX_YAML_BYTES`, checked before it is read;
- the nodes that aliases add when expanded: at most `MAX_YAML_ALIAS_NODES` (each `*name` adds the size of
  the node its anchor marks, so nine aliases of nine aliases of ... are counted as what they become);
- nesting: at most `MAX_YAML_DEPTH` levels (the composers after the scan recurse once per level);
- an alias to a node that contains it, or to no anchor at all, is refused;
- with `mapping=True` (a config file: Hydra and samp's readers take only mappings), a file whose top node is
  a list or a plain value is refused, so that such a file is named here rather than failing later where its
  keys are read.

A file that is not YAML at all is refused with its line and column. Every refusal is a `YamlFileError`
(a ValueError) naming the file: the command lines print it as one line and exit 2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["MAX_YAML_ALIAS_NODES", "MAX_YAML_BYTES", "MAX_YAML_DEPTH", "YamlFileError", "check_yaml", "load_config",
           "load_yaml"]

MAX_YAML_BYTES = 1 << 20  # 1 MiB: samp's largest config is a few kB; a description, never data
MAX_YAML_ALIAS_NODES = 100_000  # nodes aliases may add when expanded; a real config's aliases add tens
MAX_YAML_DEPTH = 64  # nesting levels; samp's configs nest fewer than ten


class YamlFileError(ValueError):
    """A YAML file refused before it is loaded: too large, expanding without bound, or not YAML."""


def _parser_loader():
    import yaml

    return getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when built with it: the same events, faster


def _where(err) -> str:
    """`problem at line L, column C` of a PyYAML error, on one line."""
    mark = getattr(err, "problem_mark", None)
    problem = getattr(err, "problem", None) or " ".join(str(err).split())
    context = getattr(err, "context", None)
    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{f'{context}: ' if context else ''}{problem}{at}"


def check_yaml(path: str | Path, what: str = "YAML file", max_bytes: int = MAX_YAML_BYTES,
               mapping: bool = False) -> bytes:
    """The bytes of `path` after checking the bounds of the module docstring (and, with `mapping`, that it
    holds a mapping or nothing); YamlFileError naming `what` and the file otherwise."""
    import yaml
    from yaml.events import (AliasEvent, CollectionEndEvent, CollectionStartEvent, MappingStartEvent, ScalarEvent,
                             StreamEndEvent)

    path = Path(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise YamlFileError(f"{what} {path} holds {size} bytes, more than the {max_bytes} a YAML file may have "
                            "(samp.yaml_files); split it, or keep data in a data file and name it")
    data = path.read_bytes()
    sizes: dict[str, int] = {}  # anchor -> nodes of its node, expanded
    stack: list[list] = []  # open collections: [nodes so far, anchor]
    added = 0  # nodes the aliases add
    top = None  # the first node's event: what the file holds
    try:
        for event in yaml.parse(data, Loader=_parser_loader()):
            if top is None and isinstance(event, (CollectionStartEvent, ScalarEvent, AliasEvent, StreamEndEvent)):
                top = event
            if isinstance(event, CollectionStartEvent):
                stack.append([1, event.anchor])
                if len(stack) > MAX_YAML_DEPTH:
                    line = event.start_mark.line + 1 if event.start_mark else "?"
                    raise YamlFileError(f"{what} {path} nests deeper than {MAX_YAML_DEPTH} levels (line {line}); "
                                        "flatten it")
                continue
            if isinstance(event, ScalarEvent):
                nodes, anchor = 1, event.anchor
            elif isinstance(event, CollectionEndEvent):
                nodes, anchor = stack.pop()
            elif isinstance(event, AliasEvent):
                anchor, line = None, event.start_mark.line + 1 if event.start_mark else "?"
                if event.anchor not in sizes:
                    inside = any(a == event.anchor for _, a in stack)
                    raise YamlFileError(f"{what} {path}: alias *{event.anchor} (line {line}) "
                                        + ("refers to a node that contains it" if inside else "has no anchor before it")
                                        + "; write the value out")
                nodes = sizes[event.anchor]
                added += nodes
                if added > MAX_YAML_ALIAS_NODES:
                    raise YamlFileError(f"{what} {path}: its aliases expand to more than {MAX_YAML_ALIAS_NODES} nodes "
                                        f"(by *{event.anchor}, line {line}): a YAML alias bomb, or far more repetition "
                                        "than a config needs; write the values out or use fewer aliases")
            else:  # stream and document start and end
                continue
            if anchor is not None:
                sizes[anchor] = nodes
            if stack:
                stack[-1][0] += nodes
    except yaml.YAMLError as err:
        raise YamlFileError(f"{what} {path} is not valid YAML: {_where(err)}; fix the file") from None
    if mapping and not isinstance(top, (MappingStartEvent, StreamEndEvent)):
        held = (f"the value {top.value[:40]!r}" if isinstance(top, ScalarEvent) else
                "an alias" if isinstance(top, AliasEvent) else "a list")
        if not (isinstance(top, ScalarEvent) and top.value == "" and not top.tag):  # an empty document: no keys
            raise YamlFileError(f"{what} {path} holds {held}, not a mapping of keys to values as every config "
                                "file does; write it as `key: value` lines")
    return data


def load_yaml(path: str | Path, what: str = "YAML file", max_bytes: int = MAX_YAML_BYTES) -> Any:
    """`yaml.safe_load` of a file that passed `check_yaml`."""
    import yaml

    data = check_yaml(path, what, max_bytes)
    try:
        return yaml.load(data, Loader=_parser_loader())
    except yaml.YAMLError as err:  # what the scan cannot see: a duplicate anchor, an unknown tag
        raise YamlFileError(f"{what} {path} is not valid YAML: {_where(err)}; fix the file") from None


def load_config(path: str | Path, what: str = "config file"):
    """`OmegaConf.load` of a file that passed `check_yaml` (OmegaConf's own loader: its number rules and
    duplicate-key check)."""
    import yaml
    from omegaconf import OmegaConf

    check_yaml(path, what)
    try:
        return OmegaConf.load(path)
    except yaml.YAMLError as err:
        raise YamlFileError(f"{what} {path} is not valid YAML: {_where(err)}; fix the file") from None
