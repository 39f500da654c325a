"""Redraw a finished run's learning curve from its ``results.json``, without touching the run.

    python scripts/plot_curve.py RUN_DIR OUT.png
    python scripts/plot_curve.py results/ippo_shopping_v2 docs/training_curve.png   # the docs'

Draws what ``python -m baselines.train`` draws into ``RUN_DIR/curve.png``
(`baselines.runs.plot_run`): the sampled training-episode profit over seeds, the validation
evaluations, the final held-out evaluation and the held-out references as lines.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from baselines.runs import plot_run


def main(argv=None) -> Path:
    """Run the command line ``argv`` (default ``sys.argv[1:]``).

    Args:
        argv: ``RUN_DIR OUT.png``.

    Returns:
        The image written.
    """
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path, help="a run directory of python -m baselines.train")
    p.add_argument("out", type=Path, help="the PNG to write")
    a = p.parse_args(argv)
    results = json.loads((a.run_dir / "results.json").read_text())
    path = plot_run(results, a.out)
    print(f"wrote {path}")
    return path


if __name__ == "__main__":
    main()
