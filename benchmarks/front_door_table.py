"""The table of issue 22: every front-door case of tests/front_door.py, run through ``selfcal`` in this process.

    python benchmarks/front_door_table.py [--markdown FILE]

Columns: case | exit | message (the last error line, paths shortened) | input untouched | output left. The
totals line counts tracebacks, damaged inputs, stray temporary names and cases whose exit was not the expected one.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

from front_door import CASES, Workspace, run_case  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--markdown", metavar="FILE", help="also write the table to FILE")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="front-door-") as root:
        ws = Workspace(root)
        rows = ["| # | case | exit | message | input untouched | output left |", "|---|---|---|---|---|---|"]
        outcomes = []
        for k, case in enumerate(CASES, start=1):
            o = run_case(ws, case)
            outcomes.append(o)
            message = o.message.replace(root + os.sep, "").replace(root, "").replace("|", "\\|")
            if len(message) > 160:
                message = message[:157] + "..."
            rows.append(f"| {k} | {case.name.replace('|', '/')} | {o.exit} | {message} | "
                        f"{'yes' if o.input_untouched else 'NO'} | {o.output_left} |")
    totals = (f"{len(outcomes)} cases: {sum(o.traceback for o in outcomes)} tracebacks, "
              f"{sum(not o.input_untouched for o in outcomes)} inputs damaged, "
              f"{sum(len(o.strays) for o in outcomes)} stray files, "
              f"{sum(o.exit not in o.expected for o in outcomes)} unexpected exit codes, "
              f"{sum(not o.ok for o in outcomes)} cases failing any check")
    text = "\n".join(rows) + "\n\n" + totals + "\n"
    print(text)
    if args.markdown:
        with open(args.markdown, "w", encoding="utf-8") as handle:
            handle.write(text)
    return 0 if all(o.ok for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
