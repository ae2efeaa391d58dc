"""``litege eval matching`` with LiteGE ablation rows (issue 15) until the CLI has ``--variants``.

Usage:
    python scripts/eval_matching_variants.py --variants tnet,judged,judged+zoomout \\
        --settings template --real tosca,tosca-landmarks --pairs 8 --queries 100 [--json out.json]

Variants (:class:`litege_core.evaluation.matching.LiteGEVariant`): a frames token (``auto``,
``tnet``, ``judged``) and any of ``mirror-vote`` and ``zoomout``, joined by ``+``. Every other
option is the one of ``litege eval matching`` (same defaults).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from litege_core.evaluation.matching import (
    load_matching_model,
    machine_header,
    results_table,
    run_matching_evaluation,
)


def _split(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--variants", default="auto")
    parser.add_argument("--pairs", type=int, default=20)
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--settings", default="template")
    parser.add_argument("--real", default="tosca,tosca-landmarks,faust")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--baselines", default="nn,zoomout")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-rotate", action="store_true")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = load_matching_model(args.model, args.device)

    def log(message: str) -> None:
        print(f"litege: {message}", file=sys.stderr, flush=True)

    results = run_matching_evaluation(
        model,
        settings=_split(args.settings),
        real=_split(args.real),
        eval_data=args.eval_data,
        n_pairs=args.pairs,
        n_queries=args.queries,
        baselines=_split(args.baselines),
        seed=args.seed,
        device=args.device,
        rotate_input=not args.no_rotate,
        workers=args.workers,
        log=log,
        variants=_split(args.variants),
    )
    meta = {
        "model": f"{model.name} ({model.content_hash[:12]})",
        "device": str(model.device),
        "pairs/set": str(args.pairs),
        "queries/pair": str(args.queries),
        "seed": str(args.seed),
        "command": "python " + " ".join(sys.argv),
    }
    header = machine_header(meta)
    print(results_table(results, header))
    if args.json:
        data = {"meta": header, "results": [r.to_dict() for r in results]}
        Path(args.json).write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
