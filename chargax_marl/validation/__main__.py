"""``python -m chargax_marl.validation``: the held-out comparison of simulated and real
charging sessions (`chargax_marl.validation.report`), written as JSON and Markdown."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from chargax_marl.core.data_io import SESSION_MODELS
from chargax_marl.validation import report


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and write ``OUT.json`` and ``OUT.md``.

    Args:
        argv: command-line arguments (default: ``sys.argv[1:]``).

    Returns:
        0 when every statistic passes its threshold, 1 otherwise.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=int, default=364, help="simulated days per comparison")
    parser.add_argument("--seed", type=int, default=0, help="the evaluation key's seed")
    parser.add_argument(
        "--out",
        default="outputs/validation/sessions",
        help="output prefix (OUT.json, OUT.md; default outputs/validation/sessions)",
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
    result = report.run(args.days, args.seed, session_model=args.session_model)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    text = report.markdown(result)
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0 if report.all_pass(result) else 1


if __name__ == "__main__":
    raise SystemExit(main())
