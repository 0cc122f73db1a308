"""Evaluate a trained run (or the expert, or the straight line) on a benchmark of unseen scenes, with the
same code as `python -m samp.eval`, and print the success rate with its Wilson 95 % interval.

    python examples/evaluate_run.py runs/quickstart/<timestamp> --benchmark unseen --problems 50
    python examples/evaluate_run.py straight --benchmark smoke        # the floor, no training needed

The benchmark is generated once if it is missing (conf/dataset/bench_<name>.yaml).
"""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("planner", help="a run folder, or expert, or straight")
    parser.add_argument("--benchmark", default="unseen", help="conf/dataset/bench_NAME.yaml")
    parser.add_argument("--problems", type=int, default=None, help="at most this many (default: all)")
    args = parser.parse_args(argv)

    from samp.eval import dataset_grids, evaluate, load_planner, problems_from_dataset
    from samp.eval.benchmark import open_benchmark

    bench = open_benchmark(args.benchmark)
    problems = problems_from_dataset(bench, "test", count=args.problems, seed=0)
    robot = bench.manifest["robot"]["name"]
    planner = load_planner(args.planner, robot=robot) if args.planner in ("expert", "straight") else \
        load_planner(args.planner)
    result = evaluate(planner, problems, grids=dataset_grids(bench), progress_s=10.0)
    m = result["metrics"]["test"]
    print(f"{result['planner']} on {bench.name}@{bench.id}: {m['problems']} problems, success "
          f"{100 * m['success_rate']:.1f} % [{100 * m['success_rate_ci_low']:.1f}, {100 * m['success_rate_ci_high']:.1f}], "
          f"collision {100 * m['collision_rate']:.1f} %")


if __name__ == "__main__":
    main()
