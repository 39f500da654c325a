"""``python -m chargax_marl.validation``: the held-out comparison of simulated and real
charging sessions (`chargax_marl.validation.report`), written as JSON and Markdown."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from chargax_marl.core import checks
from chargax_marl.core.data_io import SESSION_MODELS
from chargax_marl.validation import report


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and write ``OUT.json`` and ``OUT.md``.

    Args:
        argv: command-line arguments (default: ``sys.argv[1:]``).

    Returns:
        0 when every statistic passes its threshold, 1 otherwise.

    Raises:
        SystemExit: a bad option (``--days`` below 7, ``--seed`` outside ``[0, 2**31 - 1]``,
            an ``--out`` prefix that cannot be written: empty, under a file, no write access),
            refused before the comparison runs.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=int, default=364, help="simulated days per comparison")
    parser.add_argument("--seed", type=int, default=0, help="the evaluation key's seed")
    parser.add_argument(
        "--out",
        default="outputs/validation/sessions",
        help="output prefix, kept as typed (OUT.json, OUT.md; default outputs/validation/sessions)",
    )
    parser.add_argument(
        "--session-model",
        choices=[m for m in SESSION_MODELS if m != "paper"],
        default=report.SESSION_MODEL,
        help=f"the session model validated (default {report.SESSION_MODEL})",
    )
    args = parser.parse_args(argv)
    if args.days < 7:
        parser.error(f"--days must be at least 7 (a week), got {args.days}")
    if not 0 <= args.seed <= 2**31 - 1:
        parser.error(f"--seed must be an integer in [0, 2**31 - 1], got {args.seed}")
    try:  # before the comparison runs (minutes): a destination it cannot write is refused now
        out = checks.output_path("--out", args.out, "prefix")
    except ValueError as e:
        parser.error(str(e))
    result = report.run(args.days, args.seed, session_model=args.session_model)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out + ".json").write_text(json.dumps(result, indent=1) + "\n")
    text = report.markdown(result)
    Path(out + ".md").write_text(text)
    print(text)
    return 0 if report.all_pass(result) else 1


if __name__ == "__main__":
    raise SystemExit(main())
