"""`python -m samp.data COMMAND [key=value ...]`: generate, merge, list, show, verify and inspect datasets; push
and pull them through remotes."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from samp.cli import compose, run_command

USAGE = """usage: python -m samp.data COMMAND [key=value ...]
  generate dataset=NAME [workers=N] [shard=i num_shards=n] [root=DIR]   plan and write a dataset (resumable)
  merge dataset=NAME [root=DIR]         join the scene files of all shards into one dataset
  ls [root=DIR]                         the datasets in the registry
  show dataset=REF [root=DIR]           a dataset's manifest: spec, counts, splits, provenance
  verify dataset=REF [root=DIR]         re-hash every file; names each file that differs (exit 1)
  inspect dataset=REF [root=DIR]        per-scene and per-generator statistics, MCAP channels and schemas
  import source=PATH[,PATH] name=NAME [robot=panda] [scene=REF] [val=REF,...] [resolutions=40]
         [eval_problems=4] [max_jump=0.5] [key=observation.state] [columns=i,j,...] [root=DIR]
                                        trajectories recorded elsewhere (.npz, HDF5, a LeRobot folder) as a
                                        dataset: checked like the expert's, resampled, the refused counted
  push dataset=REF remote=URL [force=true] [root=DIR]
                                        upload a dataset to a remote (file://, s3://, hf://)
  pull dataset=NAME@ID remote=URL [root=DIR]
                                        download one, each file checked (or dataset=<remote>/datasets/NAME@ID)
For generate and merge, dataset=NAME is a spec, conf/dataset/NAME.yaml (`+dataset=NAME` is read the same),
and dataset.KEY=VALUE changes one of its settings. Elsewhere REF is NAME (the newest), NAME@ID (an id
prefix is enough) or a dataset folder, and may be given bare: `python -m samp.data verify quickstart`.
A bare NAME means the id that samp.lock (or $SAMP_LOCK) pins, when a lock file is in effect
(`python -m samp.train experiment=NAME --lock` writes one)."""


def _help() -> str:
    from samp.cli import config_names, settings_help, wrap

    return (f"{USAGE}\n\ndataset specs (dataset=NAME; conf/dataset/NAME.yaml):\n{wrap(config_names('dataset'))}\n\n"
            f"generate and merge options (key=default; conf/data.yaml):\n{settings_help('data')}")


def _config(overrides: list[str]):
    from samp.data.spec import check_overrides

    check_overrides(overrides)  # `dataset.heldout_scenes=1` names the keys that replaced it
    # conf/data.yaml's defaults list names no dataset: `dataset=NAME` adds the spec, as `+dataset=NAME` does
    cfg = compose("data", [f"+{o}" if o.startswith("dataset=") else o for o in overrides])
    if "dataset" not in cfg:
        from samp.data.spec import available_specs

        raise ValueError(f"say which dataset spec to use: dataset=NAME with NAME in {available_specs()}")
    return cfg


def _root(cfg_or_args) -> Path | None:
    root = cfg_or_args.get("root") if hasattr(cfg_or_args, "get") else None
    return Path(root) if root else None


def _generate(overrides: list[str]) -> None:
    from omegaconf import OmegaConf

    from samp.data.generation import GenerationInterrupted, generate
    from samp.data.lifecycle import reproducible_mkl

    reproducible_mkl()  # before anything in this process calls MKL: with workers=1 it plans here
    cfg = _config(overrides)
    spec = OmegaConf.to_container(cfg.dataset, resolve=True)
    try:
        dest = generate(spec, shard=cfg.shard, num_shards=cfg.num_shards, workers=cfg.workers, root=_root(cfg),
                        progress=cfg.progress)
    except GenerationInterrupted as err:  # Ctrl-C: one line, the conventional exit status of SIGINT
        print(err, file=sys.stderr)
        raise SystemExit(130) from None
    if dest is not None:
        _print_summary(dest)


def _merge(overrides: list[str]) -> None:
    from omegaconf import OmegaConf

    from samp.data.generation import merge

    cfg = _config(overrides)
    _print_summary(merge(OmegaConf.to_container(cfg.dataset, resolve=True), _root(cfg)))


def _print_summary(folder: Path) -> None:
    from samp.data.registry import read_manifest

    from samp.console import plural

    m = read_manifest(folder)
    c = m["counts"]
    print(f"dataset {m['name']}@{m['id']} in {folder}")
    print(f"  {plural(c['scenes'], 'scene')} ({c['train_scenes']} train, {c['val_scenes']} val, {c['test_scenes']} test), "
          f"{plural(c['trajectories'], 'demonstration')} ({plural(c['failures'], 'problem')} failed), "
          f"{plural(c['eval_problems'], 'evaluation problem')} ({c['eval_failures']} unsolved by the expert), planner time "
          f"{m['planning_time']['total_s'] + m['eval_planning_time']['total_s']:.1f} s")


def _parse(args: list[str], needs_ref: bool, keys: tuple[str, ...] = ()) -> tuple[str | None, dict]:
    """(the dataset reference, the options): `dataset=REF` or a bare REF (`ref=REF`, the older key, too),
    `root=DIR` and the command's own `keys`."""
    from samp.cli import parse_options

    bare, opts, _ = parse_options(args, ("dataset", "ref", "root", *keys), positional="REF" if needs_ref else None,
                                  command="this command (see `python -m samp.data --help`)")
    refs = bare + [opts.pop(k) for k in ("dataset", "ref") if k in opts]
    if len(refs) > 1:
        raise ValueError(f"one dataset at a time, got {refs}")
    if needs_ref and not refs:
        raise ValueError("say which dataset: dataset=REF, with REF a NAME, NAME@ID or folder (list them with "
                         "`python -m samp.data ls`)")
    return (refs[0] if refs else None), opts


def _ls(args: list[str]) -> None:
    from samp.data.registry import DatasetError, datasets_root, list_datasets, read_manifest

    _, opts = _parse(args, needs_ref=False)
    root = _root(opts) or datasets_root()
    rows = list_datasets(root)
    if not rows:
        print(f"no datasets under {root}; generate one with `python -m samp.data generate +dataset=quickstart`")
        return
    width = max(32, *(len(d["name"]) + 1 + len(d["id"]) for d in rows))
    print(f"{'name@id':<{width}} {'created':<32} {'scenes':>6} {'trajs':>7} {'eval':>6} {'MB':>8}")
    for d in rows:
        if not d.get("damaged"):  # list_datasets reads manifests only: a file truncated or missing shows here
            try:
                read_manifest(Path(d["path"]))
            except DatasetError as err:
                d["damaged"] = str(err)
        if d.get("damaged"):
            print(f"{d['name'] + '@' + d['id']:<{width}} DAMAGED: {d['damaged']}")
            continue
        # Every file below the dataset folder: robot SDF sample sets keep theirs in sub-folders.
        mb = sum(f.stat().st_size for f in Path(d["path"]).rglob("*") if f.is_file()) / 1e6
        counts = d.get("counts", {})
        print(f"{d['name'] + '@' + d['id']:<{width}} {d['created']:<32} {counts.get('scenes', '-'):>6} "
              f"{counts.get('trajectories', '-'):>7} {counts.get('eval_problems', '-'):>6} {mb:8.1f}")


def _show(args: list[str]) -> None:
    from samp.console import plural
    from samp.data.registry import read_manifest, resolve_ref

    ref, opts = _parse(args, needs_ref=True)
    folder = resolve_ref(ref, _root(opts))
    m = read_manifest(folder)
    shown = {k: v for k, v in m.items() if k not in ("files", "scenes")}
    config = dict(shown.get("config", {}))
    for key in ("expert_config", "generator_configs"):  # long; the full text is in manifest.json
        if key in config:
            config[key] = f"(resolved, {len(json.dumps(config[key]))} characters: see {folder / 'manifest.json'})"
    shown["config"] = config
    shown["files"] = f"{plural(len(m['files']), 'file')}, {sum(f['size'] for f in m['files'].values()) / 1e6:.1f} MB"
    print(f"# {folder}")
    print(json.dumps(shown, indent=2, sort_keys=True))


def _verify(args: list[str]) -> None:
    from samp.data.registry import resolve_ref, verify_dataset

    ref, opts = _parse(args, needs_ref=True)
    folder = resolve_ref(ref, _root(opts))
    problems = verify_dataset(folder)
    if problems:
        print(f"dataset {folder} FAILED verification:", file=sys.stderr)
        for p in problems:
            print(f"  {p}", file=sys.stderr)
        raise SystemExit(1)
    from samp.data.registry import read_manifest

    hashed = read_manifest(folder, check_sizes=False).get("format_version", 1) >= 2
    print(f"dataset {folder}: every file matches its sha256, and the scene files hold what the manifest says"
          + (" (its own hash matches too)" if hashed else " (format version 1: the manifest carries no hash of its own)"))


def _inspect(args: list[str]) -> None:
    import numpy as np
    from mcap.reader import make_reader

    from samp.data.dataset import open_dataset

    ref, opts = _parse(args, needs_ref=True)
    ds = open_dataset(ref, _root(opts))
    print(repr(ds))
    print(f"{'scene':<28} {'generator':<10} {'split':<6} {'demos':>9} {'eval':>9} {'ee path m':>10} {'plan s':>8}")
    by_gen: dict[str, list[int]] = {}
    for i, s in enumerate(ds.manifest["scenes"]):
        demos = [e for e in ds.episodes if e["scene"] == i]
        evals = [p for p in ds.eval_problems if p["scene"] == i]
        ok = [e for e in demos + evals if e["success"]]
        solved = sum(p["success"] for p in evals)
        by_gen.setdefault(s["generator"], [0, 0])
        by_gen[s["generator"]][0] += len(ok)
        by_gen[s["generator"]][1] += len(demos) + len(evals)
        ee = np.mean([e["stats"]["ee_path_length"] for e in ok]) if ok else float("nan")
        times = s["planning_time"] + s.get("eval_planning_time", [])
        print(f"{s['name']:<28} {s['generator']:<10} {ds.scene_split[i]:<6} {len(ok) - solved:>4}/{len(demos):<4} "
              f"{solved:>4}/{len(evals):<4} {ee:10.3f} {np.mean(times) if times else 0:8.2f}")
    print("expert success rate per generator: " +
          ", ".join(f"{g} {a / max(b, 1):.0%} ({a}/{b})" for g, (a, b) in by_gen.items()))
    print(_detour_line(ds.manifest["config"].get("detour_share"), ds.episodes, ds.eval_problems))
    for what, records in (("demonstration", ds.episodes), ("evaluation problem", ds.eval_problems)):
        reasons: dict[str, int] = {}
        for e in records:
            if not e["success"]:
                key = e["reason"].split(":")[0]
                reasons[key] = reasons.get(key, 0) + 1
        if reasons:
            ranked = sorted(reasons.items(), key=lambda kv: -kv[1])
            print(f"{what} failures: " + ", ".join(f"{k} x{v}" for k, v in ranked))
    with open(ds.path / ds.manifest["scenes"][0]["file"], "rb") as f:
        summary = make_reader(f).get_summary()
    stats = summary.statistics
    print(f"MCAP {ds.manifest['scenes'][0]['file']}: {stats.message_count} messages, {stats.chunk_count} chunks")
    for cid, ch in sorted(summary.channels.items()):
        schema = summary.schemas.get(ch.schema_id)
        print(f"  {ch.topic:<17} {ch.message_encoding:<9} {schema.name if schema else '-':<22} "
              f"{stats.channel_message_counts.get(cid, 0):>6} messages")


IMPORT_KEYS = ("source", "name", "robot", "scene", "val", "resolutions", "eval_problems", "max_jump", "key", "columns",
               "root", "progress")


def _import(args: list[str]) -> None:
    from samp.cli import parse_options
    from samp.console import plural
    from samp.data.importing import ImportConfig, import_dataset

    _, opts, _ = parse_options(args, IMPORT_KEYS, lists=("source", "val", "resolutions", "columns"),
                               command="import (see `python -m samp.data --help`)")
    for key in ("source", "name"):
        if key not in opts:
            raise ValueError(f"import needs {key}=...: `python -m samp.data import source=demos.npz name=mydemos "
                             "[scene=REF]` (see docs/datasets.md, Importing demonstrations)")
    ints = lambda key: [int(v) for v in opts[key]] if key in opts else None  # noqa: E731
    cfg = ImportConfig(name=opts["name"], robot=opts.get("robot", "panda"), scene=opts.get("scene"),
                       val=opts.get("val"), resolutions=tuple(ints("resolutions") or (40,)),
                       eval_problems_per_scene=int(opts.get("eval_problems", 4)),
                       max_jump=float(opts.get("max_jump", 0.5)), key=opts.get("key", "observation.state"),
                       columns=ints("columns"))
    if not (cfg.max_jump > 0 and cfg.max_jump < 10) or cfg.eval_problems_per_scene < 0:
        raise ValueError(f"max_jump must be in (0, 10) radians and eval_problems >= 0, got {cfg.max_jump}, "
                         f"{cfg.eval_problems_per_scene}")
    folder, summary = import_dataset([Path(s) for s in opts["source"]], cfg, _root(opts),
                                     progress=str(opts.get("progress", "true")).lower() != "false")
    print(f"imported {summary['kept']} of {plural(summary['kept'] + summary['refused'], 'trajectory', 'trajectories')} "
          f"({summary['refused']} refused)")
    for reason in summary["reasons"]:
        print(f"  refused {reason}")
    _print_summary(folder)


def _push(args: list[str]) -> None:
    from samp.cli import flag
    from samp.data.sharing import push_dataset

    ref, opts = _parse(args, needs_ref=True, keys=("remote", "force"))
    if not opts.get("remote"):
        raise ValueError("say where to push: remote=URL (file:///srv/samp, s3://bucket/samp, hf://datasets/ORG/REPO)")
    url, sent, kept = push_dataset(ref, opts["remote"], _root(opts), force=flag("force", opts.get("force", "false")))
    from samp.console import plural

    print(f"pushed {url}: {plural(sent, 'file')} uploaded, {kept} already there")


def _pull(args: list[str]) -> None:
    from samp.data.sharing import pull_dataset

    ref, opts = _parse(args, needs_ref=True, keys=("remote",))
    folder, got, kept = pull_dataset(ref, opts.get("remote"), _root(opts))
    if got + kept == 0:
        print(f"dataset {folder.parent.name}@{folder.name} is here already, and every file matches its sha256: {folder}")
    else:
        from samp.console import plural

        print(f"pulled {folder.parent.name}@{folder.name} into {folder}: {plural(got, 'file')} downloaded, {kept} kept "
              "(intact); every file matches its sha256 and the dataset its id")


def _detour_line(wanted, episodes: list[dict], eval_problems: list[dict]) -> str:
    """The share of problems whose straight start-goal line is blocked (recorded per problem from format 3)."""
    parts = []
    for what, records in (("demonstrations", episodes), ("evaluation problems", eval_problems)):
        known = [e["detour"] for e in records if e.get("detour") is not None]
        if records and not known:
            return "detour share: not recorded (scene files before format 3)"
        if known:
            parts.append(f"{sum(known) / len(known):.0%} of {what} ({sum(known)}/{len(known)} with a goal)")
    return (f"detour share (straight start-goal line blocked): {', '.join(parts) or 'no problems'}; the spec asks "
            f"for at least {float(wanted or 0.0):.0%}")


def main(argv: list[str] | None = None) -> int:
    commands = {"generate": _generate, "merge": _merge, "ls": _ls, "show": _show, "verify": _verify,
                "inspect": _inspect, "import": _import, "push": _push, "pull": _pull}
    return run_command(argv, _help, commands)


if __name__ == "__main__":
    sys.exit(main())
