"""``go-pipeline dag``: the pipeline's steps in run order with their inputs and outputs (like ``dvc dag``),
or Graphviz ``--dot`` / JSON."""

from __future__ import annotations

import argparse
import json

from go_pipeline.pipeline import SCENE_INPUT


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("dag", help="print the pipeline's DAG (steps, inputs, outputs)")
    p.add_argument("--pipeline", metavar="FILE", help="pipeline.yaml to show (default: the packaged one)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--dot", action="store_true", help="Graphviz dot (e.g. `| dot -Tpng > dag.png`)")
    fmt.add_argument("--json", action="store_true", help="JSON: step -> {inputs, outputs, downstream}")
    p.set_defaults(func=main)


def dag_lines(pipeline) -> list[str]:
    """One line per step in run order: ``name  <- upstream, ...  -> outputs``, then who uses it."""
    width = max(len(n) for n in pipeline.steps)
    downstream = {
        n: sorted(s for s in pipeline.steps if n in pipeline.steps[s].upstream) for n in pipeline.steps
    }
    lines = []
    for i, (name, spec) in enumerate(pipeline.steps.items(), 1):
        ups = ["(scene folder)" if u == SCENE_INPUT else u for u in dict.fromkeys(spec.inputs.values())]
        lines.append(
            f"{i:>2}. {name:<{width}}  <- {', '.join(ups) or '(nothing)'}"
            f"   => {', '.join(spec.outputs)}"
            + (f" (sometimes {', '.join(spec.optional_outputs)})" if spec.optional_outputs else "")
            + (f"   -> {', '.join(downstream[name])}" if downstream[name] else "")
        )
    return lines


def dag_dot(pipeline) -> str:
    edges = ['  "scene folder" [shape=folder];']
    for name, spec in pipeline.steps.items():
        edges.append(f'  "{name}" [shape=box];')
        for up in dict.fromkeys(spec.inputs.values()):
            edges.append(f'  "{"scene folder" if up == SCENE_INPUT else up}" -> "{name}";')
    return "digraph pipeline {\n  rankdir=LR;\n" + "\n".join(edges) + "\n}"


def main(args: argparse.Namespace) -> int:
    from go_pipeline.pipeline import load_pipeline

    pipeline = load_pipeline(args.pipeline)
    if args.dot:
        print(dag_dot(pipeline))
    elif args.json:
        print(
            json.dumps(
                {
                    n: {
                        "inputs": dict(s.inputs),
                        "outputs": list(s.outputs),
                        "optional_outputs": list(s.optional_outputs),
                        "downstream": [d for d in pipeline.steps if n in pipeline.steps[d].upstream],
                    }
                    for n, s in pipeline.steps.items()
                },
                indent=2,
            )
        )
    else:
        print("\n".join(dag_lines(pipeline)))
    return 0
