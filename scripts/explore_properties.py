"""The open-ended search of the property tests, which the suite runs derandomized.

    python scripts/explore_properties.py [--rounds 5] [pytest arguments...]

Runs every hypothesis test (pytest's `hypothesis` marker) under the "explore" profile of
tests/conftest.py, each round with a fresh seed, and prints the falsifying examples found.
A failure found this way becomes an @example of its test, so the gating suite keeps it.
Not part of the suite: it may run for minutes and its verdict depends on the seeds drawn.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="seeds to try (default 5)")
    args, extra = ap.parse_known_args()
    env = dict(os.environ, DELTASLICE_HYPOTHESIS="explore")
    found = []
    for r in range(args.rounds):
        seed = random.SystemRandom().randrange(2**32)
        cmd = [sys.executable, "-m", "pytest", "-m", "hypothesis", "-p", "no:cacheprovider",
               f"--hypothesis-seed={seed}", *extra]
        out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        summary = re.findall(r"^=*\s*(\d+ (?:passed|failed).*?)\s*=*$", out.stdout, re.M)
        print(f"round {r + 1}/{args.rounds} seed {seed}: {summary[-1] if summary else 'no summary'}", flush=True)
        if out.returncode not in (0, 5):
            falsifying = re.findall(r"^(?:E\s+)?Falsifying (?:explicit )?example:.*?(?=^\S|\Z)", out.stdout, re.M | re.S)
            found.append((seed, falsifying or [out.stdout[-3000:]]))
    for seed, examples in found:
        print(f"\nseed {seed} (rerun: DELTASLICE_HYPOTHESIS=explore python -m pytest -m hypothesis "
              f"--hypothesis-seed={seed}):")
        for ex in examples:
            print(ex.rstrip())
    print(f"\n{len(found)} of {args.rounds} rounds found a failure")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
