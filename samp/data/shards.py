"""Dataset shards through a Hydra launcher (multirun): one job per shard, local or on a cluster.

    python -m samp.data.shards -m +dataset=standard num_shards=4 'shard=range(0,4)' hydra/launcher=shards_joblib
    python -m samp.data.shards -m +dataset=paper num_shards=40 'shard=range(0,40)' workers=8 \\
        hydra/launcher=shards_slurm hydra.launcher.partition=NAME
    python -m samp.data merge +dataset=paper

Each job runs `samp.data.generate` for its shard (resuming finished scenes); the shard that completes
the set merges the dataset, and `merge` does it explicitly. Same config as `python -m samp.data generate`.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from samp.paths import conf_dir


@hydra.main(config_path=str(conf_dir()), config_name="data", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from pathlib import Path

    from samp.data.generation import generate

    if "dataset" not in cfg:
        raise ValueError("say which dataset spec to use: +dataset=NAME (see conf/dataset/)")
    # Progress bars of parallel jobs would interleave; each job prints its summary instead.
    generate(OmegaConf.to_container(cfg.dataset, resolve=True), shard=cfg.shard, num_shards=cfg.num_shards,
             workers=cfg.workers, root=Path(cfg.root) if cfg.root else None, progress=False)


if __name__ == "__main__":
    import sys

    from samp.data.spec import check_overrides

    try:  # before Hydra, which would only say that the key is not in the config
        check_overrides(sys.argv[1:])
    except ValueError as err:
        sys.exit(f"error: {err}")
    import os

    from samp.paths import project_dir

    os.chdir(project_dir())  # Hydra's sweep folder (runs/data_shards/ unless SAMP_RUNS_DIR): from the project folder, as elsewhere
    main()
