"""SPTM's graph of one house: its size, shortcuts and plans between all place pairs.

Builds SPTM's graph (every 20th frame, retrieval shortcuts) from every
drive of one house and plans between all ordered pairs of its places, from
the exact and from a jittered start
(:func:`topodrake.baselines.sptm.place_pairs_study`): graph size, shortcut
count and their true lengths, the share of pairs with a plan, and how often
top-1 localization lands within 1 m of the true pose.

    python studies/sptm_graph.py --world test-0 --out results/sptm_graph.json
"""

from __future__ import annotations

import json
import sys

from topodrake.apps import argtypes as at


def main(argv=None) -> int:
    from topodrake.apps.study_args import study_main

    ap = at.Parser(description=at.plain(__doc__.split("\n\n")[0]))
    ap.add_argument("--checkpoint", default="checkpoints/sptm_retrieval/checkpoint.pt",
                    help="retrieval checkpoint")
    ap.add_argument("--world", default="test-0", help="house")
    ap.add_argument("--demos", default="data/demos/pairs-s0/test-0",
                    help="demonstration folder of that house")
    ap.add_argument("--seed", type=at.seed, default=0, help="seed of the start jitter")
    ap.add_argument("--threads", type=at.count, default=1, help="torch threads")
    ap.add_argument("--out", help="JSON file to write (default: print only)")
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return study_main(_run, args)


def _run(args) -> int:
    import torch

    from topodrake.baselines.retrieval_net import RetrievalScorer
    from topodrake.baselines.sptm import SptmConfig, place_pairs_study
    from topodrake.fileio import atomic_write_json
    from topodrake.learning.checkpoint import git_revision

    torch.set_num_threads(args.threads)
    net = RetrievalScorer.from_checkpoint(args.checkpoint)
    result = place_pairs_study(args.world, args.demos, net, seed=args.seed)
    result = {"command": "python studies/sptm_graph.py " + " ".join(args.argv),
              "git_revision": git_revision(), "checkpoint_sha1": net.fingerprint(),
              "config": SptmConfig().__dict__, **result}
    if args.out:
        atomic_write_json(args.out, result)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
