"""``litege eval matching --variants`` for the LiteGE ablation rows (issue 15), as a script: the
same options (one definition, :func:`litege_core.cli.evaluate.add_matching_arguments`), with
``--settings template`` as the default, ``--threads``, the command line in the table header and
the JSON written compactly.

Usage:
    python scripts/eval_matching_variants.py --variants tnet,judged,judged+zoomout \\
        --settings template --real tosca,tosca-landmarks --pairs 8 --queries 100 [--json out.json]

Variants (:class:`litege_core.evaluation.matching.LiteGEVariant`): a frames token (``auto``,
``tnet``, ``judged``) and any of ``mirror-vote`` and ``zoomout`` (or ``zoomout-hybrid``), joined
by ``+``. Every other option is the one of ``litege eval matching`` (same defaults, except
``--settings``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from litege_core.cli.evaluate import add_matching_arguments, evaluate_matching
from litege_core.evaluation.matching import results_table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_matching_arguments(parser)
    parser.set_defaults(settings="template")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    results, header = evaluate_matching(args, {"command": "python " + " ".join(sys.argv)})
    print(results_table(results, header))
    if args.json:
        data = {"meta": header, "results": [r.to_dict() for r in results]}
        Path(args.json).write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main()
