"""``selfcal adjust --ap auto`` against a single tested adjustment on the paper-scale block (issue 44: <= 3x).

Seed 000's block as the README's demo simulates it (28 images, about 80,000 image observations, a local + Brown
lens field, 0.3 % blunders), Type 3. Both runs are :func:`selfcal.workflows.adjust.adjust_block` as ``selfcal
adjust`` calls it (robust cleaning and data snooping by default, no screening, no leave-one-out of the control),
in the same process, alternately:

* ``--ap wavelet:db4``: one tested adjustment;
* ``--ap auto``: the reference's tested adjustment, the image-space pre-filter of 26 candidates, the
  cross-validation of the short list, and the tested adjustment of the chosen model.

    python benchmarks/bench_model_choice.py [--repeat 3] [--candidates auto]

Prints each run's seconds, the median ratio, and the chosen model with its stages' seconds.
"""
from __future__ import annotations

import argparse
import sys
import time


def main(argv: list[str] | None = None) -> int:
    from selfcal.allocator import keep_freed_memory
    from selfcal.block import prune
    from selfcal.simulate import simulate_uav
    from selfcal.workflows.adjust import AdjustRequest, adjust_block, ap_candidates
    from selfcal.adjust import AdjustOptions, APOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--candidates", default="auto")
    parser.add_argument("--single", default="wavelet:db4", help="the single tested adjustment's AP model")
    args = parser.parse_args(argv)
    keep_freed_memory()
    block = prune(simulate_uav(seed=1, distortion="local+brown", blunder_rate=0.003).blocks["type3"])
    single = AdjustRequest(options=AdjustOptions(ap=APOptions(args.single)), control_loo=False)
    auto = AdjustRequest(options=AdjustOptions(ap=APOptions("none")), control_loo=False,
                         candidates=ap_candidates(args.candidates, (9, 6)))
    adjust_block(block, AdjustRequest(options=AdjustOptions(ap=APOptions("brown")), control_loo=False))  # JIT, tables
    times: dict[str, list[float]] = {"single": [], "auto": []}
    chosen = ""
    for _ in range(args.repeat):
        for name, request in (("single", single), ("auto", auto)):
            t0 = time.perf_counter()
            adjusted = adjust_block(block, request)
            times[name].append(time.perf_counter() - t0)
            if adjusted.choice is not None:
                chosen = next(s.label for s in adjusted.choice.candidates
                              if (s.model, s.grid) == (adjusted.choice.model, adjusted.choice.grid))
            del adjusted
    med = {k: sorted(v)[len(v) // 2] for k, v in times.items()}
    print(f"{len(block.images)} images, {len(block.observations)} image observations; {len(auto.candidates)} "
          f"candidates; chosen {chosen}")
    print(f"single tested adjustment ({args.single}): " + ", ".join(f"{t:.2f}" for t in times["single"]) + " s")
    print(f"--ap {args.candidates}: " + ", ".join(f"{t:.2f}" for t in times["auto"]) + " s")
    print(f"--ap {args.candidates} / single tested adjustment (medians): {med['auto'] / med['single']:.2f} "
          f"(issue 44: <= 3)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
