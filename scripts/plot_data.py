#!/usr/bin/env python3
"""Write overview PNGs of the bundled data into docs/.

    python scripts/plot_data.py            # docs/prices_<name>.png and docs/profile_<name>.png

One PNG per bundled price dataset (with the default profile and fleet) and one
per user profile (with the default prices and fleet), dpi 80.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from chargax_marl import data  # noqa: E402
from chargax_marl.core import datasets as ds  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs")
    args = ap.parse_args(argv)
    written = []
    for name in ds.PRICE_DATASETS:
        written.append(
            data.plot_profiles(
                prices=name,
                user_profile="shopping",
                fleet="EU",
                path=args.out / f"prices_{name}.png",
            )
        )
    for name in ds.ALL_USER_PROFILES:
        fleet = "US" if name in ds.US_USER_PROFILES else "EU"
        written.append(
            data.plot_profiles(
                prices="NL-2023",
                user_profile=name,
                fleet=fleet,
                path=args.out / f"profile_{name}.png",
            )
        )
    for p in written:
        print(
            f"{p.relative_to(ROOT) if p.is_relative_to(ROOT) else p}  {p.stat().st_size // 1024} KB"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
